// Stage 1 (collision/colliding_points.cc): the colliding points and their
// tetrahedra, against brute force, and the work they took.

#include <gtest/gtest.h>

#include <algorithm>
#include <limits>
#include <numbers>
#include <random>
#include <string>
#include <vector>

#include "collision/broad_phase.h"
#include "collision/collision_object.h"
#include "collision/geometry.h"
#include "collision/penetration.h"
#include "mesh/generators.h"
#include "tests/collision/brute_force.h"
#include "tests/collision/scene_helpers.h"

namespace tetcosim {
namespace {

using testing::BruteForceInside;
using testing::CrowdedScene;
using testing::ExpectBorderPointsMatchBruteForce;
using testing::ExpectSameCollidingPoints;
using testing::ExpectSameCollidingPointsAtThreeCellSizes;
using testing::ExpectSameResults;
using testing::Pose;
using testing::TestScene;

TEST(CollidingPoints, HashMatchesBruteForceOnRandomScenes) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> offset(-0.06, 0.06);
  std::uniform_real_distribution<double> angle(0.0, std::numbers::pi);
  const char* shapes[] = {"box:size=0.05,0.04,0.03:res=4", "sphere:size=0.05:res=1",
                          "torus:size=0.05,0.02:res=2", "capsule:size=0.02,0.03:res=3"};
  for (int trial = 0; trial < 8; ++trial) {
    TestScene scene;
    for (int k = 0; k < 4; ++k) {
      Eigen::Vector3d axis(offset(rng), offset(rng), offset(rng) + 0.01);
      scene.Add(TetMesh::Build(MakeShape(shapes[(trial + k) % 4])),
                Pose({offset(rng), offset(rng), offset(rng)}, angle(rng), axis),
                k == 3 && trial % 2);
    }
    SCOPED_TRACE(trial);
    ExpectSameCollidingPointsAtThreeCellSizes(scene);
  }
}

TEST(CollidingPoints, HashMatchesBruteForceInCrowdedScenes) {
  // objects with many partners read every vertex near a tetrahedron at
  // once, the others their partners' vertices only; both against brute
  // force
  for (int trial = 0; trial < 4; ++trial) {
    SCOPED_TRACE(trial);
    ExpectSameCollidingPointsAtThreeCellSizes(CrowdedScene(trial));
  }
}

// The work counted in PenetrationStats: every colliding point was found by
// a vertex-in-tetrahedron test, and every border point's crossings by
// segment-triangle tests, while the hash leaves out nearly all of the
// pairs a brute-force search would test (the paper's cubes 10% into each
// other: about 500 tests, against about a million pairs).
TEST(CollidingPoints, WorkIsCountedAndPrunedByTheHash) {
  TestScene scene;
  const char* cube = "box:size=0.05,0.05,0.05:res=5,5,10:split=5";
  scene.Add(TetMesh::Build(MakeShape(cube)), Pose({0, 0, 0}));
  scene.Add(TetMesh::Build(MakeShape(cube)), Pose({0.09, 0.011, -0.007}, 0.1));
  PenetrationSolver solver;
  solver.Solve(scene.objects);
  const PenetrationStats& stats = solver.stats();
  ASSERT_GT(stats.colliding, 50);
  ASSERT_GT(stats.border, 20);
  const TetMesh& a = *scene.meshes[0];
  const TetMesh& b = *scene.meshes[1];
  const std::int64_t brute_tet_pairs =
      std::int64_t{a.num_vertices()} * b.num_tets() + std::int64_t{b.num_vertices()} * a.num_tets();
  EXPECT_GE(stats.tet_tests, stats.colliding);
  EXPECT_LE(stats.tet_tests, brute_tet_pairs / 100);
  const std::int64_t brute_triangle_pairs =
      std::int64_t{stats.intersection_edges} * std::max(a.surface().rows(), b.surface().rows());
  EXPECT_GE(stats.intersection_edges, stats.border);
  EXPECT_GE(stats.triangle_tests, stats.border);
  EXPECT_LE(stats.triangle_tests, brute_triangle_pairs / 20);
  // the closest method has no stage 2
  PenetrationOptions closest;
  closest.method = DepthMethod::kClosest;
  PenetrationSolver closest_solver(closest);
  closest_solver.Solve(scene.objects);
  EXPECT_EQ(closest_solver.stats().tet_tests, stats.tet_tests);
  EXPECT_EQ(closest_solver.stats().triangle_tests, 0);
}

TEST(CollidingPoints, RowsAlongEachAxisMatchBruteForce) {
  // the broad phase sweeps along the axis where the objects spread most: a
  // row of overlapping bodies along x, y or z (jittered a little across
  // it), each against brute force
  for (int axis = 0; axis < 3; ++axis) {
    SCOPED_TRACE(axis);
    std::mt19937 rng(5 + axis);
    std::uniform_real_distribution<double> jitter(-0.004, 0.004);
    TestScene scene;
    for (int k = 0; k < 12; ++k) {
      Eigen::Vector3d at(jitter(rng), jitter(rng), jitter(rng));
      at[axis] += 0.035 * k;
      scene.Add(TetMesh::Build(MakeShape(k % 2 ? "sphere:size=0.025:res=1"
                                               : "box:size=0.04,0.035,0.03:res=2")),
                Pose(at, jitter(rng) * 100), /*rigid=*/k % 5 == 4);
    }
    ExpectSameCollidingPointsAtThreeCellSizes(scene);
    PenetrationSolver solver;
    solver.Solve(scene.objects);
    EXPECT_GT(solver.stats().colliding, 0);
  }
}

// A layer of 576 paper spheres (24 x 24, each overlapping its neighbours,
// one in five rigid): the broad phase cuts it into strips (from 512
// objects); the same colliding points as brute force, on one thread and
// two.
TEST(CollidingPoints, PileInStripsMatchesBruteForce) {
  const TestScene scene = testing::SphereLayer(24, 13);
  std::vector<BroadPhaseBox> boxes;
  for (const CollisionObject& object : scene.objects) {
    const PositionBounds bounds = PositionBounds::Of(*object.positions);
    boxes.push_back({bounds.lo, bounds.hi, object.rigid, object.self_collision});
  }
  BroadPhase broad_phase;  // (as the solver's sees the layer)
  broad_phase.Find(boxes);
  ASSERT_GE(broad_phase.num_strips(), 8);
  ASSERT_GT(BruteForceInside(scene).size(), 1000u);
  for (int threads : {1, 2}) {
    SCOPED_TRACE(threads);
    PenetrationOptions options;
    options.num_threads = threads;
    ExpectSameCollidingPoints(scene, options);
  }
}

// Tetrahedra over more than 512 cells (a coarse box half in a finely meshed
// ball, at cells of 2 mm) are searched after the chunks: a few (box res 1)
// test every hashed vertex; many (res 3) look up a coarser grid of the
// vertices, unless one covers more of its cells than there are vertices
// over four (the same scene 40 times larger: each tet of the box over 10^5
// of those cells). Every way, the same colliding points as brute force,
// the box's vertices in the ball and the ball's in the box.
TEST(CollidingPoints, LargeTetrahedraMatchBruteForce) {
  for (const auto& [box, ball, cell] :
       {std::tuple{"box:size=0.06:res=1", "sphere:size=0.05:res=3", 0.002},
        std::tuple{"box:size=0.06:res=3", "sphere:size=0.05:res=3", 0.002},
        std::tuple{"box:size=2.4:res=3", "sphere:size=2:res=3", 0.002}}) {
    SCOPED_TRACE(box);
    const double size = std::stod(std::string(box).substr(9));
    TestScene scene;
    scene.Add(box, {0, 0, 0});
    scene.Add(ball, {size, 0.1 * size, 0.2 * size});
    ASSERT_GT(BruteForceInside(scene).size(), 100u);
    PenetrationOptions options;
    options.cell_size = cell;
    ExpectSameCollidingPoints(scene, options);
  }
}

// The crowded scene ten thousand kilometres from the origin, with 1 mm
// cells: its cell coordinates (10^10) lie beyond the clamped grid (2^30),
// so every vertex and triangle shares the boundary cells. Colliding
// points, border points and closest features still match brute force.
TEST(CollidingPoints, FarBeyondTheGridMatchesBruteForce) {
  TestScene scene = CrowdedScene(0);
  const Eigen::Vector3d far(1e7, -1e7, 3e6);
  for (auto& x : scene.positions) x->rowwise() += far.transpose();
  PenetrationOptions options;
  options.cell_size = 0.001;
  ExpectSameCollidingPoints(scene, options);
  // (positions there round to 2e-9 m: depths agree to a few of those steps)
  ExpectBorderPointsMatchBruteForce(scene, 0.001, 1e-7);
  options.method = DepthMethod::kClosest;
  PenetrationSolver solver(options);
  solver.Solve(scene.objects);
  ASSERT_GT(solver.results().size(), 20u);
  for (const PenetrationResult& r : solver.results()) {
    const CollisionObject& b = scene.objects[r.penetrated];
    const Triangles& surface = b.mesh->surface();
    const Eigen::Vector3d p = scene.objects[r.object].positions->row(r.vertex).transpose();
    double best = 1e300;
    for (Eigen::Index f = 0; f < surface.rows(); ++f) {
      if (r.object == r.penetrated && (surface.row(f).array() == r.vertex).any()) continue;
      const Eigen::Vector3d c =
          ClosestPointOnTriangle(p, b.positions->row(surface(f, 0)),
                                 b.positions->row(surface(f, 1)), b.positions->row(surface(f, 2)));
      best = std::min(best, (c - p).norm());
    }
    EXPECT_NEAR(r.depth, best, 1e-15) << "object " << r.object << " vertex " << r.vertex;
  }
}

// An object with a NaN or infinite position (a caller whose state has
// diverged) is left out and counted: the rest of the scene gets, bit for
// bit, the results it gets with that object far away instead (where the
// folded bar still collides with itself: those results are not compared).
TEST(CollidingPoints, NonFiniteObjectsAreLeftOut) {
  for (double bad :
       {std::numeric_limits<double>::quiet_NaN(), std::numeric_limits<double>::infinity()}) {
    for (int object : {0, 3, 15}) {  // the large box, a small body, the folded bar
      TestScene broken = CrowdedScene(1);
      TestScene away = CrowdedScene(1);
      (*broken.positions[object])(2, 1) = bad;
      *away.positions[object] = away.positions[object]->array() + 1000.0;
      for (DepthMethod method : {DepthMethod::kConsistent, DepthMethod::kClosest}) {
        for (int threads : {1, 2}) {
          SCOPED_TRACE(::testing::Message()
                       << bad << " in object " << object << ", method " << DepthMethodName(method)
                       << ", " << threads << " threads");
          PenetrationOptions options;
          options.method = method;
          options.num_threads = threads;
          PenetrationSolver solver(options), reference(options);
          const std::vector<PenetrationResult>& results = solver.Solve(broken.objects);
          std::vector<PenetrationResult> expected = reference.Solve(away.objects);
          std::erase_if(expected, [&](const PenetrationResult& r) { return r.object == object; });
          EXPECT_EQ(solver.stats().non_finite_objects, 1);
          EXPECT_EQ(reference.stats().non_finite_objects, 0);
          ASSERT_GT(expected.size(), 20u);
          ExpectSameResults(expected, results, "left out against far away");
        }
      }
    }
  }
}

TEST(CollidingPoints, VerticesOnCellBoundaries) {
  // grid-aligned boxes whose vertices sit exactly on cell boundaries, and
  // touch exactly along faces
  TestScene scene;
  scene.Add("box:size=0.1,0.1,0.1:res=4", {0, 0, 0});
  scene.Add("box:size=0.05,0.05,0.05:res=2", {0.1, 0.05, 0.0});
  scene.Add("box:size=0.05,0.05,0.05:res=2", {-0.1, -0.15, 0.05}, /*rigid=*/true);
  for (double cell : {0.05, 0.025, 0.1}) {
    PenetrationOptions options;
    options.cell_size = cell;
    ExpectSameCollidingPoints(scene, options);
  }
}

}  // namespace
}  // namespace tetcosim
