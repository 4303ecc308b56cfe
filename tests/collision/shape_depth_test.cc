#include "collision/shape_depth.h"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "tests/collision/scene_helpers.h"

namespace tetcosim {
namespace {

using testing::TestScene;

// A wall |z| <= h, unbounded in x and y, as a solid given by functions:
// inside, the closest feature (the nearer face); where an edge from
// outside enters it, through the face on the outside point's side.
struct Wall {
  double h;
  bool Inside(const Eigen::Vector3d& p, ShapePoint& point) const {
    if (!(std::abs(p.z()) < h)) return false;
    point.depth = h - std::abs(p.z());
    point.direction = Eigen::Vector3d(0.0, 0.0, p.z() >= 0.0 ? 1.0 : -1.0);
    return true;
  }
  ShapeCrossing Crossing() const {
    return [h = h](const Eigen::Vector3d& outside, const Eigen::Vector3d& inside,
                   Eigen::Vector3d& crossing, Eigen::Vector3d& normal) {
      const double face = outside.z() > 0.0 ? h : -h;
      const double t = (outside.z() - face) / (outside.z() - inside.z());
      crossing = outside + t * (inside - outside);
      normal = Eigen::Vector3d(0.0, 0.0, face > 0.0 ? 1.0 : -1.0);
      return true;
    };
  }
};

std::vector<ShapePoint> PointsInside(const Wall& wall, const Positions& x) {
  std::vector<ShapePoint> points;
  for (int v = 0; v < x.rows(); ++v) {
    ShapePoint point;
    point.vertex = v;
    if (wall.Inside(x.row(v).transpose(), point)) points.push_back(point);
  }
  return points;
}

// A slab pushed from above 1.6 cm into a wall 2 cm thick, past its middle
// (the paper's Fig. 1 against a solid that is not a mesh): every point
// inside gets the depth h - z and the direction +z, the way it came, where
// the closest feature pushes the points past the middle out through the
// far side.
TEST(ShapeDepth, SlabPastTheMiddleOfAWallIsPushedBackTheWayItCame) {
  const Wall wall{0.01};
  const double delta = 0.016;  // layers at z = 0.009, 0.004, -0.001, -0.006
  TestScene scene;
  const int slab =
      scene.Add("box:size=0.05,0.05,0.01:res=10,10,4", {0.003, -0.002, wall.h - delta + 0.01});
  const TetMesh& mesh = *scene.meshes[slab];
  const Positions& x = *scene.positions[slab];
  std::vector<ShapePoint> points = PointsInside(wall, x);
  ASSERT_EQ(points.size(), 11u * 11u * 4u);
  int through = 0;  // the closest feature's way out is through the far side
  for (const ShapePoint& point : points) through += point.direction.z() < 0.0;
  EXPECT_EQ(through, 11 * 11 * 2);

  ShapeDepthSolver solver;
  solver.Solve(mesh, x, points, wall.Crossing());
  int border = 0, propagated = 0;
  for (const ShapePoint& point : points) {
    const double z = x(point.vertex, 2);
    EXPECT_NEAR(point.depth, wall.h - z, 1e-15) << "vertex " << point.vertex;
    EXPECT_NEAR((point.direction - Eigen::Vector3d::UnitZ()).norm(), 0.0, 1e-15);
    border += point.source == DepthSource::kBorder;
    propagated += point.source == DepthSource::kPropagated;
    // border points: the top layer, whose neighbours above are outside
    EXPECT_EQ(point.source == DepthSource::kBorder, z > 0.005) << "vertex " << point.vertex;
  }
  EXPECT_EQ(border, 11 * 11);
  EXPECT_EQ(propagated, 11 * 11 * 3);
}

// A slab inside a wall far thicker than it: no edge crosses the surface, so
// the method reaches none of its points, which keep the closest feature's
// values, flagged; and the same for edges whose crossings are not found.
TEST(ShapeDepth, PointsTheMethodDoesNotReachKeepTheClosestFeature) {
  TestScene scene;
  const int slab = scene.Add("box:size=0.05,0.05,0.01:res=4", {0.0, 0.0, 0.3});
  const TetMesh& mesh = *scene.meshes[slab];
  const Positions& x = *scene.positions[slab];
  ShapeDepthSolver solver;
  const Wall thick{1.0};
  std::vector<ShapePoint> points = PointsInside(thick, x);
  ASSERT_EQ(static_cast<Eigen::Index>(points.size()), x.rows());
  const std::vector<ShapePoint> before = points;
  solver.Solve(mesh, x, points, thick.Crossing());
  const Wall thin{0.31};  // (the slab's top layer outside)
  std::vector<ShapePoint> cut = PointsInside(thin, x);
  ASSERT_LT(cut.size(), points.size());
  const std::vector<ShapePoint> cut_before = cut;
  solver.Solve(mesh, x, cut,
               [](const Eigen::Vector3d&, const Eigen::Vector3d&, Eigen::Vector3d&,
                  Eigen::Vector3d&) { return false; });
  for (auto [after, original] : {std::pair(&points, &before), std::pair(&cut, &cut_before)}) {
    for (size_t k = 0; k < after->size(); ++k) {
      EXPECT_EQ((*after)[k].source, DepthSource::kFallback);
      EXPECT_EQ((*after)[k].depth, (*original)[k].depth);
      EXPECT_EQ((*after)[k].direction, (*original)[k].direction);
    }
  }
  // the thin wall again, its crossings found: every point from them
  solver.Solve(mesh, x, cut, thin.Crossing());
  for (const ShapePoint& point : cut) EXPECT_NE(point.source, DepthSource::kFallback);
}

}  // namespace
}  // namespace tetcosim
