#include "mujoco_bridge/geom_shape.h"

#include <gtest/gtest.h>
#include <mujoco/mujoco.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <functional>
#include <limits>
#include <memory>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "mesh/error.h"
#include "mujoco_bridge/world.h"
#include "tests/mujoco_bridge/temp_dir.h"

namespace tetcosim {
namespace {

using MjRotation = Eigen::Matrix<double, 3, 3, Eigen::RowMajor>;

// a compiled model and its data after mj_forward
struct Compiled {
  mjModel* m = nullptr;
  mjData* d = nullptr;
  Compiled() = default;
  Compiled(const Compiled&) = delete;
  Compiled& operator=(const Compiled&) = delete;
  ~Compiled() {
    if (d) mj_deleteData(d);
    if (m) mj_deleteModel(m);
  }
  Eigen::Vector3d ToWorld(int geom, const Eigen::Vector3d& p_G) const {
    return Eigen::Map<const Eigen::Vector3d>(d->geom_xpos + 3 * geom) + Rotation(geom) * p_G;
  }
  Eigen::Matrix3d Rotation(int geom) const {
    return Eigen::Map<const MjRotation>(d->geom_xmat + 9 * geom);
  }
  // MuJoCo's distance from p_G along the unit u_G (both geom frame) to the
  // surface of `geom`, the only geom of its group; -1 where the ray misses
  double Ray(int geom, const Eigen::Vector3d& p_G, const Eigen::Vector3d& u_G) const {
    mjtByte groups[mjNGROUP] = {};
    groups[m->geom_group[geom]] = 1;
    const Eigen::Vector3d p_W = ToWorld(geom, p_G);
    const Eigen::Vector3d u_W = Rotation(geom) * u_G;
    int hit = -1;
    return mj_ray(m, d, p_W.data(), u_W.data(), groups, 1, -1, &hit);
  }
};

std::unique_ptr<Compiled> Compile(const TempDir& dir, const std::string& xml) {
  const std::string path = dir.Write("model.xml", xml);
  char error[1000] = "";
  auto compiled = std::make_unique<Compiled>();
  compiled->m = mj_loadXML(path.c_str(), nullptr, error, sizeof(error));
  if (!compiled->m) {
    ADD_FAILURE() << error;
    return nullptr;
  }
  compiled->d = mj_makeData(compiled->m);
  mj_forward(compiled->m, compiled->d);
  return compiled;
}

Eigen::Vector3d RandomDirection(std::mt19937& rng) {
  std::normal_distribution<double> normal;
  return Eigen::Vector3d(normal(rng), normal(rng), normal(rng)).normalized();
}

// Every convex geom type, each alone in its group, placed off the origin
// and turned; the mesh is 40 random points on an ellipsoid (MuJoCo collides
// it as their convex hull, and its ray meets the hull's faces).
std::string ConvexGeoms() {
  std::mt19937 rng(7);
  std::ostringstream vertices;
  for (int k = 0; k < 40; ++k) {
    const Eigen::Vector3d u = RandomDirection(rng);
    vertices << 0.3 * u.x() << " " << 0.2 * u.y() << " " << 0.15 * u.z() << "  ";
  }
  return R"(<mujoco>
  <asset><mesh name="rock" vertex=")" +
         vertices.str() + R"("/></asset>
  <worldbody>
    <geom name="sphere" group="0" type="sphere" size="0.2" pos="1 2 3" euler="10 20 30"/>
    <geom name="box" group="1" type="box" size="0.3 0.2 0.1" pos="-1 0.5 0" euler="40 -10 5"/>
    <geom name="capsule" group="2" type="capsule" size="0.1 0.2" pos="0 -1 1" euler="0 90 15"/>
    <geom name="cylinder" group="3" type="cylinder" size="0.15 0.1" pos="2 0 -1" euler="30 0 60"/>
    <geom name="ellipsoid" group="4" type="ellipsoid" size="0.3 0.2 0.1" pos="0 0 2" euler="5 15 25"/>
    <geom name="rock" group="5" type="mesh" mesh="rock" pos="-2 -1 0.5" euler="70 10 -20"/>
  </worldbody>
</mujoco>)";
}

// Calls check(compiled, geom, its shape, a random generator seeded with
// `seed`) for each geom of ConvexGeoms().
void ForEachConvexGeom(
    unsigned seed,
    const std::function<void(const Compiled*, int, const GeomShape&, std::mt19937&)>& check) {
  TempDir dir("tetcosim_geom_shape");
  std::unique_ptr<Compiled> compiled = Compile(dir, ConvexGeoms());
  ASSERT_NE(compiled, nullptr);
  const mjModel* m = compiled->m;
  std::mt19937 rng(seed);
  for (int g = 0; g < m->ngeom; ++g) {
    SCOPED_TRACE(mj_id2name(m, mjOBJ_GEOM, g));
    ASSERT_GT(m->geom_rbound[g], 0.0);
    check(compiled.get(), g, MakeGeomShape(m, g, "geom"), rng);
  }
}

// Oracles, MuJoCo's rays (mj_ray) from the point: inside a convex geom every
// ray from p meets its surface, and none nearer than the depth; the one
// along the direction meets it at the depth. Outside one, a separating
// plane turns half of all rays away: one of 32 misses but with odds 2^-32.
TEST(GeomShape, DepthIsTheNearestWayOutOfEveryConvexGeom) {
  ForEachConvexGeom(
      11, [](const Compiled* compiled, int g, const GeomShape& shape, std::mt19937& rng) {
        const double bound = compiled->m->geom_rbound[g];
        const double tolerance = 1e-9 * bound;
        std::uniform_real_distribution<double> coordinate(-bound, bound);
        std::vector<Eigen::Vector3d> directions(32);
        for (Eigen::Vector3d& u : directions) u = RandomDirection(rng);
        int inside = 0, outside = 0;
        while (inside < 300 || outside < 100) {
          const Eigen::Vector3d p(coordinate(rng), coordinate(rng), coordinate(rng));
          double depth = -1.0;
          Eigen::Vector3d direction = Eigen::Vector3d::Zero();
          if (GeomPenetration(shape, p, depth, direction)) {
            ++inside;
            ASSERT_GT(depth, 0.0);
            ASSERT_NEAR(direction.norm(), 1.0, 1e-12);
            ASSERT_NEAR(compiled->Ray(g, p, direction), depth, tolerance)
                << "at " << p.transpose() << ", the way out " << direction.transpose();
            for (const Eigen::Vector3d& u : directions) {
              const double distance = compiled->Ray(g, p, u);
              ASSERT_GE(distance, depth - tolerance)
                  << "at " << p.transpose() << " along " << u.transpose() << ": a nearer surface";
            }
          } else {
            ++outside;
            bool missed = false;
            for (const Eigen::Vector3d& u : directions) missed |= compiled->Ray(g, p, u) < 0.0;
            ASSERT_TRUE(missed) << p.transpose() << " is inside, every ray meets the geom";
          }
        }
      });
}

// Oracles for the consistent method's crossing (GeomEntry): MuJoCo's ray
// from the outside point toward the inside one meets the geom where the
// crossing is, and the normal there is the way out of a plane that
// supports the geom (every point found inside is on its inner side).
TEST(GeomShape, EntryIsWhereMuJoCosRayMeetsTheGeom) {
  ForEachConvexGeom(13, [](const Compiled* compiled, int g, const GeomShape& shape,
                           std::mt19937& rng) {
    const double bound = compiled->m->geom_rbound[g];
    const double tolerance = 1e-9 * bound;
    std::uniform_real_distribution<double> coordinate(-bound, bound);
    std::vector<Eigen::Vector3d> inside, outside;
    while (inside.size() < 200 || outside.size() < 200) {
      const Eigen::Vector3d p(coordinate(rng), coordinate(rng), coordinate(rng));
      double depth;
      Eigen::Vector3d direction;
      (GeomPenetration(shape, p, depth, direction) ? inside : outside).push_back(p);
    }
    for (size_t k = 0; k < 200; ++k) {
      // pairs near each other too: an edge's length, a tenth of the geom
      const Eigen::Vector3d& p = inside[k];
      const Eigen::Vector3d q =
          k % 2 == 0 ? outside[k] : Eigen::Vector3d(p + 0.1 * bound * RandomDirection(rng));
      double depth;
      Eigen::Vector3d direction;
      if (GeomPenetration(shape, q, depth, direction)) continue;
      double t = -1.0;
      Eigen::Vector3d normal = Eigen::Vector3d::Zero();
      ASSERT_TRUE(GeomEntry(shape, q, p, t, normal)) << q.transpose() << " to " << p.transpose();
      ASSERT_GE(t, 0.0);
      ASSERT_LE(t, 1.0);
      const double length = (p - q).norm();
      ASSERT_NEAR(compiled->Ray(g, q, (p - q) / length), t * length, tolerance)
          << q.transpose() << " to " << p.transpose();
      ASSERT_NEAR(normal.norm(), 1.0, 1e-12);
      const Eigen::Vector3d x = q + t * (p - q);
      for (const Eigen::Vector3d& y : inside) {
        ASSERT_LE(normal.dot(y - x), tolerance)
            << "the plane at " << x.transpose() << " with normal " << normal.transpose()
            << " cuts the geom at " << y.transpose();
      }
    }
  });
}

// The hull's planes support the mesh: each touches it (its farthest
// vertex on the plane) and has every vertex on its inner side.
TEST(GeomShape, HullPlanesSupportTheMesh) {
  TempDir dir("tetcosim_geom_shape");
  std::unique_ptr<Compiled> compiled = Compile(dir, ConvexGeoms());
  ASSERT_NE(compiled, nullptr);
  const mjModel* m = compiled->m;
  const int geom = mj_name2id(m, mjOBJ_GEOM, "rock");
  const GeomShape shape = MakeGeomShape(m, geom, "rock");
  const int mesh = m->geom_dataid[geom];
  ASSERT_GE(shape.plane_normal.size(), 4u);
  for (size_t f = 0; f < shape.plane_normal.size(); ++f) {
    double farthest = -1.0;
    for (int v = 0; v < m->mesh_vertnum[mesh]; ++v) {
      const float* x = m->mesh_vert + 3 * (m->mesh_vertadr[mesh] + v);
      const double height =
          shape.plane_normal[f].dot(Eigen::Vector3d(x[0], x[1], x[2])) - shape.plane_offset[f];
      farthest = v == 0 ? height : std::max(farthest, height);
    }
    EXPECT_NEAR(farthest, 0.0, 1e-12) << "plane " << f;
  }
}

// Where the nearest point is not unique or the bisection's bracket is
// degenerate (the centre, the planes and axes of symmetry, spheroids and a
// sphere), the point found lies on the surface, along the normal from p,
// and no point of a dense sampling of the surface is nearer.
TEST(GeomShape, EllipsoidNearestPointOnItsPlanesOfSymmetry) {
  const Eigen::Vector3d shapes[] = {
      {0.3, 0.2, 0.1}, {0.2, 0.2, 0.1}, {0.3, 0.1, 0.1}, {0.1, 0.2, 0.3}, {0.2, 0.2, 0.2}};
  for (const Eigen::Vector3d& radii : shapes) {
    SCOPED_TRACE("radii " + std::to_string(radii.x()) + " " + std::to_string(radii.y()) + " " +
                 std::to_string(radii.z()));
    std::vector<Eigen::Vector3d> surface;
    constexpr int kLongitudes = 720, kLatitudes = 360;
    for (int i = 0; i < kLongitudes; ++i) {
      for (int j = 0; j <= kLatitudes; ++j) {
        const double phi = 2.0 * M_PI * i / kLongitudes, theta = M_PI * j / kLatitudes;
        surface.emplace_back(radii.x() * std::sin(theta) * std::cos(phi),
                             radii.y() * std::sin(theta) * std::sin(phi),
                             radii.z() * std::cos(theta));
      }
    }
    std::vector<Eigen::Vector3d> points = {Eigen::Vector3d::Zero()};
    for (int axis = 0; axis < 3; ++axis) {
      for (double f : {0.3, -0.6, 0.95}) {
        points.push_back(f * radii[axis] * Eigen::Vector3d::Unit(axis));
        Eigen::Vector3d in_plane = 0.4 * f * radii;
        in_plane[axis] = 0.0;
        points.push_back(in_plane);
      }
    }
    points.push_back(Eigen::Vector3d(0.05, -0.03, 0.02).cwiseProduct(radii) * 10.0);
    for (const Eigen::Vector3d& p : points) {
      ASSERT_LT(p.cwiseQuotient(radii).squaredNorm(), 1.0);
      Eigen::Vector3d nearest, normal;
      NearestEllipsoidPoint(radii, p, nearest, normal);
      EXPECT_NEAR(nearest.cwiseQuotient(radii).squaredNorm(), 1.0, 1e-12) << p.transpose();
      EXPECT_NEAR(normal.norm(), 1.0, 1e-12);
      const Eigen::Vector3d gradient = nearest.cwiseQuotient(radii.cwiseProduct(radii));
      EXPECT_NEAR(normal.dot(gradient.normalized()), 1.0, 1e-12) << "the outward normal there";
      const double depth = (nearest - p).norm();
      if (depth > 0.0) {
        EXPECT_NEAR((nearest - p).normalized().dot(normal), 1.0, 1e-10)
            << "from p along the normal, at " << p.transpose();
      }
      double closest = INFINITY;
      for (const Eigen::Vector3d& s : surface) closest = std::min(closest, (s - p).norm());
      EXPECT_GE(closest, depth - 1e-12) << "a nearer surface point, at " << p.transpose();
      EXPECT_LE(closest, depth + 2.0 * M_PI * radii.maxCoeff() / kLatitudes)
          << "(the sampling's spacing) at " << p.transpose();
    }
  }
}

// A height field of random elevations (MuJoCo's binary format: rows, cols,
// then the elevations row by row), placed off the origin and turned.
// Oracles: MuJoCo's ray from above gives the surface's height over (x, y);
// central differences of it across a triangle give its normal.
TEST(GeomShape, HeightFieldIsMuJoCosSurfaceAsRaysSeeIt) {
  TempDir dir("tetcosim_geom_shape");
  constexpr std::int32_t kRows = 7, kCols = 9;
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> unit(0.0f, 1.0f);
  std::string bytes(reinterpret_cast<const char*>(&kRows), 4);
  bytes.append(reinterpret_cast<const char*>(&kCols), 4);
  for (int k = 0; k < kRows * kCols; ++k) {
    const float value = unit(rng);
    bytes.append(reinterpret_cast<const char*>(&value), 4);
  }
  const std::string field = dir.Write("field.bin", bytes);
  std::unique_ptr<Compiled> compiled = Compile(dir, R"(<mujoco>
  <asset><hfield name="field" file=")" + field + R"(" size="0.4 0.3 0.1 0.05"/></asset>
  <worldbody><geom type="hfield" hfield="field" pos="1 -2 0.5" euler="10 -5 40"/></worldbody>
</mujoco>)");
  ASSERT_NE(compiled, nullptr);
  const GeomShape shape = MakeGeomShape(compiled->m, 0, "field");
  ASSERT_EQ(shape.rows, kRows);
  ASSERT_EQ(shape.cols, kCols);
  const Eigen::Vector3d down = -Eigen::Vector3d::UnitZ();
  auto surface = [&](double x, double y) {  // (MuJoCo's)
    return 1.0 - compiled->Ray(0, Eigen::Vector3d(x, y, 1.0), down);
  };
  const double cell_x = 0.8 / (kCols - 1), cell_y = 0.6 / (kRows - 1);
  std::uniform_real_distribution<double> x_of(-0.4, 0.4), y_of(-0.3, 0.3), z_of(-0.08, 0.12);
  int inside = 0, outside = 0, normals = 0;
  while (inside < 300 || outside < 300) {
    const Eigen::Vector3d p(x_of(rng), y_of(rng), z_of(rng));
    const double h = surface(p.x(), p.y());
    double depth = -1.0;
    Eigen::Vector3d direction;
    const bool in = GeomPenetration(shape, p, depth, direction);
    if (p.z() < -0.05 || p.z() > h + 1e-12) {
      ASSERT_FALSE(in) << p.transpose() << ": below the base or above the surface (" << h << ")";
      ++outside;
      continue;
    }
    if (p.z() > h - 1e-12) continue;  // (on the surface, to rounding)
    ASSERT_TRUE(in) << p.transpose() << " is below the surface (" << h << ")";
    ++inside;
    ASSERT_GT(direction.z(), 0.0);
    ASSERT_NEAR(p.z() + depth / direction.z(), h, 1e-9) << "the surface over " << p.transpose();
    // the normal, where p is well inside its triangle
    double u = (p.x() + 0.4) / cell_x, v = (p.y() + 0.3) / cell_y;
    u -= std::floor(u);
    v -= std::floor(v);
    const double margin = 0.02;
    if (u < margin || u > 1 - margin || v < margin || v > 1 - margin || std::abs(u - v) < margin) {
      continue;
    }
    const double e = 1e-3 * cell_x;
    const double dh_dx = (surface(p.x() + e, p.y()) - surface(p.x() - e, p.y())) / (2 * e);
    const double dh_dy = (surface(p.x(), p.y() + e) - surface(p.x(), p.y() - e)) / (2 * e);
    const Eigen::Vector3d normal = Eigen::Vector3d(-dh_dx, -dh_dy, 1.0).normalized();
    ASSERT_NEAR(direction.dot(normal), 1.0, 1e-10) << "at " << p.transpose();
    ++normals;
  }
  EXPECT_GT(normals, 100);
  // beside the grid: outside
  double depth;
  Eigen::Vector3d direction;
  EXPECT_FALSE(GeomPenetration(shape, Eigen::Vector3d(0.41, 0.0, -0.01), depth, direction));
  EXPECT_FALSE(GeomPenetration(shape, Eigen::Vector3d(0.0, -0.31, -0.01), depth, direction));
}

// Three soft cubes dropped, one on the floor, one on a box, one on a
// ball, in two scenes that differ only in how those are given: a plane, a
// box and a sphere, or a flat height field, a mesh of the box's corners and
// an ellipsoid of equal radii. For 2 s the cubes move alike in both (the
// shapes are the same), and come to rest on what they fell on.
TEST(GeomShape, CubesMeetMeshesHeightFieldsAndEllipsoidsAsThePrimitivesTheyEqual) {
  TempDir dir("tetcosim_geom_shape");
  auto scene = [&](const std::string& floor, const std::string& box, const std::string& ball) {
    return dir.Write("scene.xml", R"(<mujoco>
  <option timestep="0.002"/>
  <asset>
    <hfield name="flat" nrow="2" ncol="2" size="1 1 0.1 0.1"/>
    <mesh name="box" vertex="-0.1 -0.1 -0.05  0.1 -0.1 -0.05  -0.1 0.1 -0.05  0.1 0.1 -0.05
                             -0.1 -0.1 0.05  0.1 -0.1 0.05  -0.1 0.1 0.05  0.1 0.1 0.05"/>
  </asset>
  <worldbody>
    )" + floor + "\n    " + box + "\n    " +
                                      ball + R"(
  </worldbody>
  <deformable>
    <contact friction="0.5"/>
    <tetbody name="on_floor" shape="box" size="0.03 0.03 0.03" resolution="3" pos="0 0.5 0.1"
             euler="5 10 0" young="1e5" damping="1 0"/>
    <tetbody name="on_box" shape="box" size="0.03 0.03 0.03" resolution="3" pos="0.5 0 0.2"
             euler="-5 0 10" young="1e5" damping="1 0"/>
    <tetbody name="on_ball" shape="box" size="0.03 0.03 0.03" resolution="3" pos="-0.5 0 0.26"
             young="1e5" damping="1 0"/>
  </deformable>
</mujoco>)");
  };
  std::unique_ptr<World> primitives =
      World::Load(scene(R"(<geom type="plane" size="1 1 0.1"/>)",
                        R"(<geom type="box" size="0.1 0.1 0.05" pos="0.5 0 0.05"/>)",
                        R"(<geom type="sphere" size="0.1" pos="-0.5 0 0.1"/>)"));
  std::unique_ptr<World> others =
      World::Load(scene(R"(<geom type="hfield" hfield="flat"/>)",
                        R"(<geom type="mesh" mesh="box" pos="0.5 0 0.05"/>)",
                        R"(<geom type="ellipsoid" size="0.1 0.1 0.1" pos="-0.5 0 0.1"/>)"));
  for (int step = 0; step < 1000; ++step) {
    primitives->Step();
    others->Step();
    ASSERT_EQ(primitives->metrics().status, StepStatus::kOk) << primitives->metrics().message;
    ASSERT_EQ(others->metrics().status, StepStatus::kOk) << others->metrics().message;
  }
  for (int i = 0; i < 3; ++i) {
    SCOPED_TRACE(i);
    const Eigen::Vector3d x = primitives->deformable(i).CenterOfMass();
    // (to 1e-7 m: MuJoCo keeps a mesh's vertices in single precision, its
    // box's 0.1 m as 0.100000001490116 m)
    EXPECT_LT((others->deformable(i).CenterOfMass() - x).norm(), 1e-7) << x.transpose();
  }
  // at rest where they fell: on the floor, on the box's top, on the ball's
  EXPECT_NEAR(others->deformable(0).CenterOfMass().z(), 0.03, 1e-3);
  EXPECT_NEAR(others->deformable(1).CenterOfMass().z(), 0.1 + 0.03, 1e-3);
  EXPECT_NEAR(others->deformable(2).CenterOfMass().z(), 0.2 + 0.03, 2e-3);
  EXPECT_LT(others->DeformableKineticEnergy(), 1e-6);
}

// A cube wholly inside a box geom has no edge that crosses the geom's
// surface: the consistent method reaches none of its vertices, which get
// the signed distance and are counted as fallback points; a cube half in
// has none, and the closest-feature method never falls back.
TEST(GeomShape, PointsTheConsistentMethodDoesNotReachAreCountedAsFallback) {
  TempDir dir("tetcosim_geom_shape");
  const char* scene = R"(<mujoco>
  <option gravity="0 0 0"/>
  <worldbody><geom name="block" type="box" size="0.5 0.5 0.5"/></worldbody>
  <deformable>
    <tetbody name="cube" shape="box" size="0.05 0.05 0.05" resolution="3" pos="0 0 %s"/>
  </deformable>
</mujoco>)";
  struct Case {
    const char* height;
    DepthMethod method;
    bool all_fallback;
  };
  for (const Case& c :
       {Case{"0", DepthMethod::kConsistent, true}, Case{"0.5", DepthMethod::kConsistent, false},
        Case{"0", DepthMethod::kClosest, false}}) {
    SCOPED_TRACE(std::string("at z = ") + c.height + ", " + DepthMethodName(c.method));
    char text[600];
    std::snprintf(text, sizeof(text), scene, c.height);
    WorldOptions options;
    options.method = c.method;
    std::unique_ptr<World> world = World::Load(dir.Write("inside.xml", text), options);
    world->Step();
    const StepMetrics& metrics = world->metrics();
    const int vertices = world->deformable(0).num_vertices();
    EXPECT_GT(metrics.colliding_points, 0);
    EXPECT_EQ(metrics.fallback_points, c.all_fallback ? vertices : 0);
  }
}

// The bundled terrain scene: soft bodies dropped on a height field and a
// convex mesh, met without proxies, and a loose ellipsoid, given a proxy
// (round, near the bodies' gaps: <contact autoproxy>). After a
// second no vertex lies deeper than 2 mm below the highest geom surface
// over it (MuJoCo's ray from above: nothing fell through), and every body
// has come down onto something.
TEST(GeomShape, BundledTerrainSceneHoldsItsBodiesUp) {
  std::unique_ptr<World> world =
      World::Load(std::string(TETCOSIM_SOURCE_DIR) + "/models/scenes/terrain.xml");
  const std::vector<World::GeomSummary> geoms = world->GeomsMetByShape();
  ASSERT_EQ(geoms.size(), 2u);
  EXPECT_EQ(geoms[0].name, "ground");
  EXPECT_EQ(geoms[0].shape, "height field 41 x 41");
  EXPECT_EQ(geoms[1].name, "rock");
  EXPECT_EQ(geoms[1].shape.rfind("mesh: convex hull of ", 0), 0u) << geoms[1].shape;
  ASSERT_EQ(world->made_proxies().size(), 1u);
  EXPECT_EQ(world->made_proxies()[0].geom, "pebble");
  std::vector<double> start_z(world->num_deformables());
  for (int i = 0; i < world->num_deformables(); ++i) {
    start_z[i] = world->deformable(i).CenterOfMass().z();
  }
  for (int step = 0; step < 500; ++step) {
    world->Step();
    ASSERT_EQ(world->metrics().status, StepStatus::kOk) << world->metrics().message;
  }
  const mjModel* m = world->mj_model();
  mjData* d = world->mj_data();
  double deepest = 0.0;
  for (int i = 0; i < world->num_deformables(); ++i) {
    const DeformableBody& body = world->deformable(i);
    EXPECT_LT(body.CenterOfMass().z(), start_z[i] - 0.02) << body.name() << " came down";
    for (int v = 0; v < body.num_vertices(); ++v) {
      const Eigen::Vector3d p = body.positions().row(v).transpose();
      const mjtNum from[3] = {p.x(), p.y(), 1.0}, down[3] = {0.0, 0.0, -1.0};
      int hit = -1;
      const double distance = mj_ray(m, d, from, down, nullptr, 1, -1, &hit);
      ASSERT_GE(distance, 0.0) << "nothing under " << body.name() << " vertex " << v;
      deepest = std::max(deepest, (1.0 - distance) - p.z());
    }
  }
  EXPECT_LT(deepest, 0.002) << "m below the geom surface over a vertex";
}

// Oracle: the geom's extents along its axes, from MuJoCo's rays through its
// centre from either side (each primitive is symmetric about its centre
// and axes), and the narrowest hole a geom passes through is the second
// smallest of them. The mesh is a box whose extents are given.
TEST(GeomShape, PassageWidthIsTheSecondSmallestExtent) {
  ForEachConvexGeom(17, [](const Compiled* compiled, int g, const GeomShape& shape, std::mt19937&) {
    if (shape.type == mjGEOM_MESH) return;
    const double far = 2.0 * compiled->m->geom_rbound[g];
    std::vector<double> extents;
    for (int k = 0; k < 3; ++k) {
      const Eigen::Vector3d u = Eigen::Vector3d::Unit(k);
      extents.push_back(2.0 * far - compiled->Ray(g, far * u, -u) - compiled->Ray(g, -far * u, u));
    }
    std::sort(extents.begin(), extents.end());
    EXPECT_NEAR(GeomPassageWidth(compiled->m, g), extents[1], 1e-9);
  });
  TempDir dir("tetcosim_geom_shape");
  std::unique_ptr<Compiled> compiled = Compile(dir, R"(<mujoco>
  <asset><mesh name="brick" vertex="0 0 0  0.3 0 0  0 0.2 0  0.3 0.2 0
                                    0 0 0.1  0.3 0 0.1  0 0.2 0.1  0.3 0.2 0.1"/>
    <hfield name="field" nrow="2" ncol="2" size="1 1 0.1 0.1"/></asset>
  <worldbody>
    <geom type="mesh" mesh="brick" euler="10 20 30"/>
    <geom type="plane" size="1 1 0.1"/>
    <geom type="hfield" hfield="field"/>
  </worldbody>
</mujoco>)");
  ASSERT_NE(compiled, nullptr);
  EXPECT_NEAR(GeomPassageWidth(compiled->m, 0), 0.2, 1e-6);  // (single precision)
  EXPECT_EQ(GeomPassageWidth(compiled->m, 1), std::numeric_limits<double>::infinity());
  EXPECT_EQ(GeomPassageWidth(compiled->m, 2), std::numeric_limits<double>::infinity());
}

// Which geoms get a proxy made for them: those narrower than the coarsest
// gaps between a deformable's surface vertices (a block of 3 cells a
// side: 4.7 cm, the cells' diagonals), and round ones up to 8 times as
// wide (spheres, ellipsoids, capsules and cylinders; autoproxy "true", the
// default; "narrow": only the narrower), that meet deformables and have no
// <rigidtet> (which a mesh geom may have too: its convex hull). With autoproxy off, each narrower
// one is warned of instead (a wider round one is not: it cannot pass through); a finer block makes
// fewer.
TEST(GeomShape, ProxiesAreMadeForGeomsNarrowerThanTheVertexSpacingAndRoundOnesNearIt) {
  TempDir dir("tetcosim_geom_shape");
  auto load = [&](int resolution, const std::string& auto_proxies) {
    std::string xml = R"(<mujoco>
  <asset><mesh name="pebble" vertex="0 0 0  0.01 0 0  0 0.01 0  0 0 0.01"/></asset>
  <worldbody>
    <geom name="floor" type="plane" size="1 1 0.1"/>
    <geom name="plate" type="box" size="0.2 0.2 0.001" pos="0 0 0.5"/>
    <geom name="big" type="sphere" size="0.03" pos="1 0 0.5"/>
    <geom name="brick" type="box" size="0.03 0.03 0.03" pos="1 1 0.5"/>
    <geom name="drum" type="cylinder" size="0.18 0.05" pos="1 2 0.5"/>
    <geom name="boulder" type="sphere" size="0.19" pos="1 3 0.5"/>
    <geom name="bar" type="capsule" size="0.03 0.07" pos="1 4 0.5"/>
    <geom name="off" type="sphere" size="0.01" pos="2 0 0.5" contype="2" conaffinity="2"/>
    <geom name="pebble" type="mesh" mesh="pebble" pos="3 0 0.5"/>
    <body name="rod" pos="4 0 0.5"><geom name="rod" type="capsule" size="0.01 0.2"/></body>
    <body name="given" pos="5 0 0.5"><geom name="given" type="sphere" size="0.01"/></body>
    <body name="stone" pos="6 0 0.5"><geom name="stone" type="mesh" mesh="pebble"/></body>
  </worldbody>
  <deformable>
    <contact autoproxy="AUTO"/>
    <rigidtet body="given" geom="given"/>
    <rigidtet body="stone" geom="stone" resolution="2"/>
    <tetbody name="block" shape="box" size="0.05 0.05 0.05" resolution="CELLS" pos="0 0 0.05"/>
  </deformable>
</mujoco>)";
    xml.replace(xml.find("AUTO"), 4, auto_proxies);
    xml.replace(xml.find("CELLS"), 5, std::to_string(resolution));
    return World::Load(dir.Write("scene.xml", xml));
  };
  auto names = [](const World& world) {
    std::string all;
    for (const World::MadeProxy& made : world.made_proxies()) all += made.geom + " ";
    return all;
  };
  auto warnings = [](const World& world) {
    std::string all;
    for (const std::string& warning : world.load_warnings()) all += warning + "\n";
    return all;
  };
  // (the drum is 0.36 m wide, the boulder 0.38: 7.6 and 8.1 gaps; the
  // bar is as wide as the big ball, and longer)
  std::unique_ptr<World> coarse = load(3, "true");
  ASSERT_EQ(names(*coarse), "big drum bar pebble rod ");
  EXPECT_EQ(coarse->num_proxies(), 7);  // given's, stone's and the five made
  EXPECT_NE(
      coarse->made_proxies()[0].why.find("round, 0.06 m wide, less than 8 times the 0.0471 m gaps"),
      std::string::npos)
      << coarse->made_proxies()[0].why;
  // (a ball 6 cm across sinks 3 - sqrt(3^2 - 2.36^2) = 1.14 cm into a
  // round gap 4.71 cm across)
  EXPECT_NE(coarse->made_proxies()[0].why.find("sink up to 0.011 m"), std::string::npos)
      << coarse->made_proxies()[0].why;
  EXPECT_NE(coarse->made_proxies()[4].why.find("0.02 m wide, less than the 0.0471 m gaps"),
            std::string::npos)
      << coarse->made_proxies()[4].why;
  EXPECT_EQ(warnings(*coarse), "");
  // a round geom's proxy: its fine surface coned to its centre (the big
  // ball: a level-3 sphere's 1280 triangles) or its axis, slab by slab (12
  // cells across: a rim of 4 n = 48 segments; layers as thick as a cell is
  // wide, each with 8 n side triangles and, between two slabs, a ring of
  // 4 n edges, two tetrahedra each; the drum's ends 2 n^2 triangles each, 3
  // layers; the bar's 28 layers, its caps 2 n^2 + 8 n c triangles each, c =
  // 6 layers of cells; the rod, 0.4 m long, 4 cells across and 80 layers,
  // c = 2, where 5 would take more than 8000)
  auto coned = [](int n, int layers, int rings, int ends) {
    return 8 * n * layers + 8 * n * rings + ends;
  };
  EXPECT_EQ(coarse->made_proxies()[0].num_tets, 1280);
  EXPECT_EQ(coarse->made_proxies()[1].num_tets, coned(12, 3, 2, 2 * 2 * 144));
  EXPECT_EQ(coarse->made_proxies()[2].num_tets, coned(12, 28, 29, 2 * (2 * 144 + 8 * 12 * 6)));
  EXPECT_EQ(coarse->made_proxies()[4].num_tets, coned(4, 80, 81, 2 * (2 * 16 + 8 * 4 * 2)));
  EXPECT_LE(coarse->made_proxies()[4].num_tets, 8000);
  std::unique_ptr<World> narrow = load(3, "narrow");
  EXPECT_EQ(names(*narrow), "pebble rod ");
  EXPECT_EQ(warnings(*narrow), "");
  std::unique_ptr<World> off = load(3, "false");
  EXPECT_EQ(names(*off), "");
  EXPECT_EQ(off->num_proxies(), 2);
  const std::string off_warnings = warnings(*off);
  EXPECT_NE(off_warnings.find("geom 'rod': 0.02 m wide, less than the 0.0471 m gaps"),
            std::string::npos)
      << off_warnings;
  EXPECT_NE(off_warnings.find("geom 'pebble': 0.0"), std::string::npos) << off_warnings;
  EXPECT_EQ(off_warnings.find("big"), std::string::npos) << off_warnings;
  // (gaps of 0.0074 m: 8 of them are 0.059 m, less than the big ball and
  // the bar, more than the rod)
  std::unique_ptr<World> fine = load(19, "true");
  EXPECT_EQ(names(*fine), "rod ");
  EXPECT_EQ(warnings(*fine), "");
  EXPECT_THROW(
      {
        try {
          load(3, "round");
        } catch (const Error& e) {
          EXPECT_NE(std::string(e.what()).find("autoproxy must be true, narrow or false"),
                    std::string::npos)
              << e.what();
          throw;
        }
      },
      Error);
}

// Oracles for the mesh of a convex hull: its tetrahedra are positive
// (none flipped), its vertices lie in the hull (every face plane's inner
// side), its surface vertices on the hull (on a face plane), it holds what
// the hull does, and its surface edges are no longer than asked (or its
// faces at their limit, 20,000). Hulls: the random rock, a tetrahedron, a cube and
// a long rod, turned.
TEST(GeomShape, ConvexHullMeshFillsTheHull) {
  TempDir dir("tetcosim_geom_shape");
  std::unique_ptr<Compiled> rocks = Compile(dir, ConvexGeoms());
  std::unique_ptr<Compiled> others = Compile(dir, R"(<mujoco>
  <asset>
    <mesh name="pebble" vertex="0 0 0  0.01 0 0  0 0.01 0  0 0 0.01"/>
    <mesh name="cube" vertex="0 0 0  1 0 0  0 1 0  1 1 0  0 0 1  1 0 1  0 1 1  1 1 1"/>
    <mesh name="rod" vertex="0 0 0  0.01 0 0  0 0.012 0  0.01 0.012 0  0 0 0.2  0.01 0 0.2
                             0 0.012 0.2  0.01 0.012 0.2"/>
  </asset>
  <worldbody>
    <geom type="mesh" mesh="pebble" euler="10 20 30"/>
    <geom type="mesh" mesh="cube" euler="-30 10 45"/>
    <geom type="mesh" mesh="rod" euler="0 90 0"/>
  </worldbody>
</mujoco>)");
  ASSERT_NE(rocks, nullptr);
  ASSERT_NE(others, nullptr);
  struct Case {
    const mjModel* m;
    int geom;
    double max_edge;
  };
  const int rock = mj_name2id(rocks->m, mjOBJ_GEOM, "rock");
  const Case cases[] = {{rocks->m, rock, 1.0}, {rocks->m, rock, 0.05}, {others->m, 0, 1.0},
                        {others->m, 0, 0.003}, {others->m, 1, 0.3},    {others->m, 2, 1.0},
                        {others->m, 2, 0.005}, {others->m, 1, 2.0}};
  for (const Case& c : cases) {
    SCOPED_TRACE("geom " + std::to_string(c.geom) + ", edges up to " + std::to_string(c.max_edge));
    const GeomShape shape = MakeGeomShape(c.m, c.geom, "geom");
    const TetMesh mesh = TetMesh::Build(ConvexHullTetMesh(c.m, c.geom, c.max_edge, "geom"));
    EXPECT_EQ(mesh.num_flipped(), 0);
    EXPECT_TRUE(mesh.warnings().empty());
    const double size = c.m->geom_rbound[c.geom];
    for (int v = 0; v < mesh.num_vertices(); ++v) {
      const Eigen::Vector3d p = mesh.positions().row(v).transpose();
      double outmost = -std::numeric_limits<double>::infinity();
      for (size_t i = 0; i < shape.plane_normal.size(); ++i) {
        outmost = std::max(outmost, shape.plane_normal[i].dot(p) - shape.plane_offset[i]);
      }
      ASSERT_LE(outmost, 1e-9 * size) << "vertex " << v << " outside the hull";
      if (mesh.is_surface_vertex(v)) {
        ASSERT_GE(outmost, -1e-9 * size) << "surface vertex " << v << " inside the hull";
      }
    }
    EXPECT_NEAR(mesh.total_volume(), shape.hull_volume, 1e-9 * shape.hull_volume);
    // edges as short as asked, unless the faces would have been too many
    double longest = 0.0;
    for (int f = 0; f < mesh.surface().rows(); ++f) {
      for (int k = 0; k < 3; ++k) {
        longest = std::max(longest, (mesh.positions().row(mesh.surface()(f, k)) -
                                     mesh.positions().row(mesh.surface()(f, (k + 1) % 3)))
                                        .norm());
      }
    }
    EXPECT_TRUE(longest <= c.max_edge || mesh.surface().rows() >= 20000)
        << longest << " m, " << mesh.surface().rows() << " faces";
  }
}

// An arrowhead (a concave quadrilateral, extruded): its hull holds 4/3 of
// its volume, which loading warns of; a convex mesh loads without warning.
TEST(GeomShape, NonConvexMeshIsWarnedOf) {
  TempDir dir("tetcosim_geom_shape");
  // A B C D counter-clockwise from +z, D the reflex corner; 0-3 at z = 0,
  // 4-7 at z = 0.1; every face wound outward
  const std::string arrowhead = R"(vertex="0 0 0  0.2 0.1 0  0 0.2 0  0.05 0.1 0
                                        0 0 0.1  0.2 0.1 0.1  0 0.2 0.1  0.05 0.1 0.1"
        face="0 3 1  3 2 1  4 5 7  7 5 6  0 1 5  0 5 4  1 2 6  1 6 5  2 3 7  2 7 6  3 0 4  3 4 7")";
  const std::string box = R"(vertex="0 0 0  0.2 0 0  0 0.2 0  0.2 0.2 0
                                  0 0 0.1  0.2 0 0.1  0 0.2 0.1  0.2 0.2 0.1")";
  auto warnings = [&](const std::string& mesh) {
    std::unique_ptr<World> world = World::Load(dir.Write("scene.xml", R"(<mujoco>
  <asset><mesh name="shape" )" + mesh + R"(/></asset>
  <worldbody><geom name="rock" type="mesh" mesh="shape"/></worldbody>
  <deformable><tetbody name="ball" shape="sphere" size="0.05" pos="0 0 1"/></deformable>
</mujoco>)"));
    std::string all;
    for (const std::string& warning : world->load_warnings()) all += warning + "\n";
    return all;
  };
  const std::string concave = warnings(arrowhead);
  EXPECT_NE(concave.find("geom 'rock': its mesh is not convex"), std::string::npos) << concave;
  EXPECT_NE(concave.find("holds 1.33 times"), std::string::npos) << concave;
  EXPECT_EQ(warnings(box), "");
}

TEST(GeomShape, MeshWithoutAHullOrAFieldWithoutASurfaceIsAClearError) {
  TempDir dir("tetcosim_geom_shape");
  auto scene = [&](const std::string& contact) {
    return dir.Write("scene.xml", R"(<mujoco>
  <compiler convexhull="false"/>
  <asset><mesh name="wedge" vertex="0 0 0  1 0 0  0 1 0  0 0 1"
                                  face="0 2 1  0 1 3  0 3 2  1 2 3"/></asset>
  <worldbody><geom name="rock" type="mesh" mesh="wedge" )" +
                                      contact + R"(/></worldbody>
  <deformable><tetbody name="ball" shape="sphere" size="0.1" pos="0 0 1"/></deformable>
</mujoco>)");
  };
  std::string message;
  try {
    World::Load(scene(""));
  } catch (const Error& e) {
    message = e.what();
  }
  ASSERT_FALSE(message.empty()) << "loaded";
  EXPECT_NE(message.find("scene.xml: geom 'rock': its mesh has no convex hull"), std::string::npos)
      << message;
  EXPECT_NE(message.find("convexhull"), std::string::npos) << message;
  // kept off deformables, it loads
  EXPECT_NO_THROW(World::Load(scene("contype=\"2\" conaffinity=\"2\"")));
  // a height field of one row has no surface (MuJoCo takes it)
  message.clear();
  try {
    World::Load(dir.Write("line.xml", R"(<mujoco>
  <asset><hfield name="line" nrow="1" ncol="5" size="1 1 0.1 0.1"/></asset>
  <worldbody><geom name="ground" type="hfield" hfield="line"/></worldbody>
  <deformable><tetbody name="ball" shape="sphere" size="0.1" pos="0 0 1"/></deformable>
</mujoco>)"));
  } catch (const Error& e) {
    message = e.what();
  }
  EXPECT_NE(message.find("line.xml: geom 'ground': its height field has 1 x 5 points"),
            std::string::npos)
      << message;
}

}  // namespace
}  // namespace tetcosim
