#include "collision/penetration.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <numbers>
#include <random>
#include <string>
#include <tuple>

#include "collision/geometry.h"
#include "mesh/error.h"
#include "mesh/same_bits.h"
#include "tests/collision/scene_helpers.h"

namespace tetcosim {
namespace {

using testing::Pose;
using testing::TestScene;

// (object, vertex, penetrated) -> containing tet, by testing every vertex
// against every tetrahedron (the oracle for the spatial hash)
std::map<std::tuple<int, int, int>, int> BruteForceInside(const TestScene& scene) {
  std::map<std::tuple<int, int, int>, std::pair<double, int>> best;
  for (int b = 0; b < static_cast<int>(scene.objects.size()); ++b) {
    const CollisionObject& ob = scene.objects[b];
    for (int t = 0; t < ob.mesh->num_tets(); ++t) {
      auto tet = ob.mesh->tets().row(t);
      Eigen::Vector3d c[4];
      for (int i = 0; i < 4; ++i) c[i] = ob.positions->row(tet[i]).transpose();
      for (int a = 0; a < static_cast<int>(scene.objects.size()); ++a) {
        const CollisionObject& oa = scene.objects[a];
        if (a == b && !ob.self_collision) continue;
        if (a != b && oa.rigid && ob.rigid) continue;
        for (int v = 0; v < oa.mesh->num_vertices(); ++v) {
          if (a == b && (tet.array() == v).any()) continue;
          Eigen::Vector4d l;
          if (!TetBarycentric(c[0], c[1], c[2], c[3], oa.positions->row(v).transpose(), l)) {
            continue;
          }
          if (l.minCoeff() < -kBarycentricTolerance) continue;
          auto key = std::make_tuple(a, v, b);
          auto it = best.find(key);
          if (it == best.end() || l.minCoeff() > it->second.first) best[key] = {l.minCoeff(), t};
        }
      }
    }
  }
  std::map<std::tuple<int, int, int>, int> out;
  for (const auto& [key, value] : best) out[key] = value.second;
  return out;
}

void ExpectSameCollidingPoints(const TestScene& scene, PenetrationOptions options) {
  PenetrationSolver solver(options);
  const auto& results = solver.Solve(scene.objects);
  auto expected = BruteForceInside(scene);
  std::map<std::tuple<int, int, int>, int> found;
  for (const PenetrationResult& r : results) found[{r.object, r.vertex, r.penetrated}] = r.tet;
  EXPECT_EQ(solver.stats().unresolved, 0);
  EXPECT_EQ(found.size(), expected.size());
  EXPECT_EQ(found, expected);
}

// the same at the default cell size, tiny cells (many distinct cells share
// buckets) and huge cells (many vertices per cell)
void ExpectSameCollidingPointsAtThreeCellSizes(const TestScene& scene) {
  for (double cell : {0.0, 0.002, 0.2}) {
    SCOPED_TRACE(cell);
    PenetrationOptions options;
    options.cell_size = cell;
    ExpectSameCollidingPoints(scene, options);
  }
}

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

// Two tetrahedra on the two sides of a triangle (radius r, apexes h above
// and below): 6 surface triangles, not a multiple of four (the solver keeps
// a small body's triangles in groups of four; the last group's other lanes
// must meet nothing).
RawMesh Bipyramid(double r, double h) {
  RawMesh raw;
  raw.positions.resize(5, 3);
  for (int i = 0; i < 3; ++i) {
    const double a = 2.0 * std::numbers::pi * i / 3.0;
    raw.positions.row(i) << r * std::cos(a), r * std::sin(a), 0.0;
  }
  raw.positions.row(3) << 0.0, 0.0, h;
  raw.positions.row(4) << 0.0, 0.0, -h;
  raw.tets.resize(2, 4);
  raw.tets << 0, 1, 2, 3, 0, 2, 1, 4;
  raw.source = "bipyramid";
  return raw;
}

// A pile of small bodies in and around a large one: a large box
// (rigid in odd trials), 14 small bodies (the paper's 20-tet spheres and a
// bipyramid of 6 triangles among them), and a bar folded into itself with
// self-collision.
TestScene CrowdedScene(int trial) {
  std::mt19937 rng(11 + trial);
  std::uniform_real_distribution<double> offset(-0.07, 0.07);
  std::uniform_real_distribution<double> angle(0.0, std::numbers::pi);
  const char* shapes[] = {"sphere:size=0.03:res=0", "box:size=0.03,0.02,0.025:res=2",
                          "capsule:size=0.01,0.02:res=2"};
  TestScene scene;
  scene.Add(TetMesh::Build(MakeShape("box:size=0.12,0.12,0.12:res=4")), Pose({0, 0, 0}),
            /*rigid=*/trial % 2 == 1);
  for (int k = 0; k < 14; ++k) {
    Eigen::Vector3d axis(offset(rng), offset(rng), offset(rng) + 0.01);
    scene.Add(TetMesh::Build(k % 4 == 3 ? Bipyramid(0.03, 0.025) : MakeShape(shapes[k % 3])),
              Pose({offset(rng), offset(rng), offset(rng)}, angle(rng), axis),
              /*rigid=*/k % 5 == 4);
  }
  int bar = scene.Add(TetMesh::Build(MakeShape("box:size=0.2,0.02,0.02:res=10,1,1")),
                      Pose({0, 0.01 * trial, 0}), false, /*self_collision=*/true);
  Positions& x = *scene.positions[bar];
  for (Eigen::Index v = 0; v < x.rows(); ++v) {
    if (x(v, 0) > 0.19) x(v, 0) = -0.03;
  }
  return scene;
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

// Stages 2 and 3 by brute force (method.md): for every colliding point p
// and neighbour q not inside B, the crossing of q -> p with any of B's
// surface triangles nearest q, its smooth normal, and the border point's
// depth and direction from the inverse-squared-distance weights; the
// solver's border points must match, whatever path found the crossings
// (small objects' triangles four at a time, the hashed grid, triangles
// too large to hash).
// (depth_tolerance: absolute, metres; positions far from the origin round
// to coarser steps)
void ExpectBorderPointsMatchBruteForce(const TestScene& scene, double cell_size,
                                       double depth_tolerance = 1e-12) {
  PenetrationOptions options;
  options.cell_size = cell_size;
  PenetrationSolver solver(options);
  const std::vector<PenetrationResult> results = solver.Solve(scene.objects);
  std::map<std::tuple<int, int, int>, const PenetrationResult*> colliding;
  for (const PenetrationResult& r : results) colliding[{r.object, r.vertex, r.penetrated}] = &r;
  std::vector<Positions> normals(scene.objects.size());
  for (size_t o = 0; o < scene.objects.size(); ++o) {
    ComputeVertexNormals(*scene.objects[o].positions, scene.objects[o].mesh->surface(), normals[o]);
  }
  const double on_surface = 1e-9 * solver.length_scale();
  int border = 0;
  for (const PenetrationResult& r : results) {
    const TetMesh& mesh_a = *scene.objects[r.object].mesh;
    const TetMesh& mesh_b = *scene.objects[r.penetrated].mesh;
    const Positions& x_a = *scene.objects[r.object].positions;
    const Positions& x_b = *scene.objects[r.penetrated].positions;
    const Triangles& surface = mesh_b.surface();
    const Eigen::Vector3d p = x_a.row(r.vertex).transpose();
    double weight_sum = 0.0, depth_sum = 0.0, nearest_distance = 1e300;
    Eigen::Vector3d normal_sum = Eigen::Vector3d::Zero();
    Eigen::Vector3d nearest_normal = Eigen::Vector3d::Zero();
    for (int n = mesh_a.adjacency_offsets()[r.vertex]; n < mesh_a.adjacency_offsets()[r.vertex + 1];
         ++n) {
      const int q_vertex = mesh_a.adjacency()[n];
      if (colliding.count({r.object, q_vertex, r.penetrated})) continue;
      const Eigen::Vector3d q = x_a.row(q_vertex).transpose();
      double best_t = 1e300, best_u = 0.0, best_v = 0.0;
      int best_f = -1;
      for (int f = 0; f < surface.rows(); ++f) {
        if (r.object == r.penetrated && ((surface.row(f).array() == r.vertex).any() ||
                                         (surface.row(f).array() == q_vertex).any())) {
          continue;  // self-collision: the edge's own triangles do not count
        }
        double t, u, v;
        if (SegmentTriangle(q, p, x_b.row(surface(f, 0)).transpose(),
                            x_b.row(surface(f, 1)).transpose(), x_b.row(surface(f, 2)).transpose(),
                            t, u, v) &&
            t < best_t) {
          best_t = t;
          best_u = u;
          best_v = v;
          best_f = f;
        }
      }
      if (best_f < 0) continue;
      const Eigen::Vector3d point = q + best_t * (p - q);
      Eigen::Vector3d normal =
          ((1.0 - best_u - best_v) * normals[r.penetrated].row(surface(best_f, 0)) +
           best_u * normals[r.penetrated].row(surface(best_f, 1)) +
           best_v * normals[r.penetrated].row(surface(best_f, 2)))
              .transpose();
      ASSERT_GT(normal.norm(), 1e-6);  // (the scenes have no cancelling vertex normals)
      normal.normalize();
      const double distance = (point - p).norm();
      if (distance < nearest_distance) {
        nearest_distance = distance;
        nearest_normal = normal;
      }
      if (distance < on_surface) continue;  // p on B's surface (the guard of stage 3)
      const double w = 1.0 / (distance * distance);
      weight_sum += w;
      depth_sum += w * (point - p).dot(normal);
      normal_sum += w * normal;
    }
    SCOPED_TRACE(::testing::Message()
                 << "object " << r.object << " vertex " << r.vertex << " in " << r.penetrated);
    if (nearest_distance == 1e300) {  // no crossing: not a border point
      EXPECT_NE(r.source, DepthSource::kBorder);
      continue;
    }
    ++border;
    ASSERT_EQ(r.source, DepthSource::kBorder);
    if (nearest_distance < on_surface || weight_sum == 0.0) {
      EXPECT_EQ(r.depth, 0.0);
      EXPECT_LT((r.direction - nearest_normal).norm(), 1e-9);
    } else {
      EXPECT_NEAR(r.depth, std::max(0.0, depth_sum / weight_sum), depth_tolerance);
      // (normals that cancel leave the nearest crossing's)
      const Eigen::Vector3d direction = normal_sum.norm() > 1e-12 * weight_sum
                                            ? Eigen::Vector3d(normal_sum.normalized())
                                            : nearest_normal;
      EXPECT_LT((r.direction - direction).norm(), 1e-9);
    }
  }
  EXPECT_GT(border, 20);  // the scene has border points at all
}

TEST(ConsistentDepth, BorderPointsMatchBruteForceInCrowdedScenes) {
  for (int trial = 0; trial < 2; ++trial) {
    const TestScene scene = CrowdedScene(trial);
    // default-like cells, tiny cells (the large box's triangles are too
    // large to hash) and huge ones
    for (double cell : {0.01, 0.002, 0.2}) {
      SCOPED_TRACE(::testing::Message() << "trial " << trial << " cell " << cell);
      ExpectBorderPointsMatchBruteForce(scene, cell);
    }
  }
}

// A coarse box (edges of 1 m and longer) with a corner in a finely meshed
// ball (cells of 5 mm): the box's edges from that corner each cover up to
// 10^7 cells, so stage 2 tests the ball's whole triangle hash instead of
// looking the cells up one by one; the border points still match brute
// force, both ways (the ball's vertices inside the box cross its large
// faces).
TEST(ConsistentDepth, LongEdgesIntoAFineBodyMatchBruteForce) {
  TestScene scene;
  scene.Add("box:size=0.5,0.5,0.5:res=1", {0, 0, 0});
  scene.Add("sphere:size=0.02:res=3", {0.5, 0.5, 0.5});
  ExpectBorderPointsMatchBruteForce(scene, 0.005);
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
          ASSERT_EQ(results.size(), expected.size());
          for (size_t i = 0; i < results.size(); ++i) {
            const PenetrationResult& x = results[i];
            const PenetrationResult& y = expected[i];
            EXPECT_EQ(std::tie(x.object, x.vertex, x.penetrated, x.tet, x.source),
                      std::tie(y.object, y.vertex, y.penetrated, y.tet, y.source));
            EXPECT_TRUE(SameBits({&x.depth, 1}, {&y.depth, 1}));
            EXPECT_TRUE(SameBits({x.direction.data(), 3}, {y.direction.data(), 3}));
          }
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

// A fine slab pushed delta into a large box through its top face: every
// colliding point of the slab has depth h - z and direction +z exactly.
TEST(ConsistentDepth, SlabIntoBoxMatchesTheAnalyticDepth) {
  const double h = 0.1;        // the box's top face is at z = h
  const double delta = 0.035;  // slab layers at depths 0.035, 0.025, 0.015, 0.005
  TestScene scene;
  int box = scene.Add("box:size=0.2,0.2,0.1:res=8,8,4", {0, 0, 0});
  int slab = scene.Add("box:size=0.05,0.05,0.025:res=10,10,5", {0.01, -0.02, h - delta + 0.025});
  PenetrationSolver solver;
  solver.Solve(scene.objects);
  int checked = 0;
  int border = 0;
  int propagated = 0;
  double max_depth = 0.0;
  for (const PenetrationResult& r : solver.results()) {
    if (r.object != slab) continue;
    EXPECT_EQ(r.penetrated, box);
    double z = scene.positions[slab]->row(r.vertex).z();
    EXPECT_NEAR(r.depth, h - z, 1e-12) << DepthSourceName(r.source);
    EXPECT_NEAR((r.direction - Eigen::Vector3d::UnitZ()).norm(), 0.0, 1e-12);
    border += r.source == DepthSource::kBorder;
    propagated += r.source == DepthSource::kPropagated;
    max_depth = std::max(max_depth, r.depth);
    ++checked;
  }
  EXPECT_EQ(checked, 11 * 11 * 4);
  EXPECT_GT(border, 0);
  EXPECT_GT(propagated, 0);
  EXPECT_NEAR(max_depth, delta, 1e-12);
  EXPECT_EQ(solver.stats().fallback, 0);
}

// The paper's Fig. 1: a cube pushed 70% of its width into another.
TEST(ConsistentDepth, DeepPenetrationPushesBackTheWayItCame) {
  const double w = 0.1;
  TestScene scene;
  int b = scene.Add("box:size=0.05,0.05,0.05:res=10", {0, 0, 0});
  // A is 80% as wide, entering B's +x face moving in -x
  int a = scene.Add("box:size=0.04,0.04,0.04:res=8", {0.5 * w - 0.7 * w + 0.04, 0.003, -0.002});
  int deep_consistent = 0;
  for (DepthMethod method : {DepthMethod::kConsistent, DepthMethod::kClosest}) {
    PenetrationOptions options;
    options.method = method;
    PenetrationSolver solver(options);
    solver.Solve(scene.objects);
    int wrong_way = 0;
    int count = 0;
    for (const PenetrationResult& r : solver.results()) {
      // A's vertices inside B: the way back is +x. (B's vertices inside A
      // near A's side faces rightly leave A sideways; they are not the claim.)
      if (r.object != a) continue;
      double cosine = r.direction.dot(Eigen::Vector3d::UnitX());
      if (method == DepthMethod::kConsistent) {
        EXPECT_GT(cosine, 0.9) << "vertex " << r.vertex;
        if (r.depth > 0.5 * w) ++deep_consistent;
      }
      wrong_way += cosine < 0.5;  // pushed to the far side or sideways
      ++count;
    }
    EXPECT_GT(count, 300);
    if (method == DepthMethod::kClosest) {
      // the artifact the paper describes
      EXPECT_GT(wrong_way, count / 4) << "closest-feature directions that do not point back";
    } else {
      EXPECT_EQ(wrong_way, 0);
    }
  }
  EXPECT_GT(deep_consistent, 0) << "consistent depths reach beyond half the width";
  EXPECT_EQ(b, 0);
}

// The paper's Fig. 2: a vertex moved in small steps under a corner of a
// coarse mesh; the consistent direction turns smoothly, the closest one jumps.
TEST(ConsistentDepth, DirectionIsContinuousUnderAnEdge) {
  const int steps = 100;
  double max_turn[2] = {0.0, 0.0};
  Eigen::Vector3d previous[2];
  for (int s = 0; s <= steps; ++s) {
    // p slides under the edge x = y = 0.5 of a one-cell box, from nearer
    // the +x face (0.1 deep) to nearer the +y face (0.1 deep)
    double f = static_cast<double>(s) / steps;
    Eigen::Vector3d p(0.4 - 0.15 * f, 0.25 + 0.15 * f, 0.05);
    // a small tetrahedron with one vertex at p and three outside the corner
    RawMesh raw;
    raw.positions.resize(4, 3);
    raw.positions.row(0) = p.transpose();
    raw.positions.row(1) = (p + Eigen::Vector3d(0.3, 0.3, 0.0)).transpose();
    raw.positions.row(2) = (p + Eigen::Vector3d(0.3, 0.3, 0.2)).transpose();
    raw.positions.row(3) = (p + Eigen::Vector3d(0.35, 0.25, -0.2)).transpose();
    raw.tets.resize(1, 4);
    raw.tets << 0, 1, 2, 3;
    TestScene step_scene;
    step_scene.Add(TetMesh::Build(MakeShape("box:size=0.5,0.5,0.5:res=1")));
    int probe = step_scene.Add(TetMesh::Build(raw));
    for (int m = 0; m < 2; ++m) {
      PenetrationOptions options;
      options.method = m == 0 ? DepthMethod::kConsistent : DepthMethod::kClosest;
      PenetrationSolver solver(options);
      solver.Solve(step_scene.objects);
      const PenetrationResult* found = nullptr;
      for (const auto& r : solver.results()) {
        if (r.object == probe && r.vertex == 0) found = &r;
      }
      ASSERT_NE(found, nullptr) << "step " << s;
      if (s > 0) {
        double turn = std::acos(std::clamp(found->direction.dot(previous[m]), -1.0, 1.0));
        max_turn[m] = std::max(max_turn[m], turn);
      }
      previous[m] = found->direction;
    }
  }
  const double degree = std::numbers::pi / 180.0;
  EXPECT_LT(max_turn[0], 3.0 * degree) << "consistent direction turns smoothly";
  EXPECT_GT(max_turn[1], 45.0 * degree) << "closest-feature direction jumps";
}

TEST(ConsistentDepth, EnclosedObjectGetsFlaggedFallbackValues) {
  TestScene scene;
  int box = scene.Add("box:size=0.2,0.2,0.2:res=4", {0, 0, 0});
  int inner = scene.Add("sphere:size=0.03:res=1", {0.05, 0.02, -0.01});
  PenetrationSolver solver;
  solver.Solve(scene.objects);
  int fallback = 0;
  for (const PenetrationResult& r : solver.results()) {
    ASSERT_EQ(r.object, inner);
    EXPECT_EQ(r.penetrated, box);
    EXPECT_EQ(r.source, DepthSource::kFallback);
    // the nearest face of the box is +x at 0.2
    Eigen::Vector3d p = scene.positions[inner]->row(r.vertex);
    double nearest = (Eigen::Vector3d::Constant(0.2) - p.cwiseAbs()).minCoeff();
    EXPECT_NEAR(r.depth, nearest, 1e-12);
    ++fallback;
  }
  EXPECT_EQ(fallback, scene.meshes[inner]->num_vertices());
  EXPECT_EQ(solver.stats().fallback, fallback);

  PenetrationOptions no_fallback;
  no_fallback.fallback = false;
  PenetrationSolver strict(no_fallback);
  EXPECT_TRUE(strict.Solve(scene.objects).empty());
  EXPECT_EQ(strict.stats().unresolved, fallback);
}

// The fallback searches all of B's surface, also the triangles already in
// play for another partner: a ball enclosed in a large box just behind its
// +x face, and a small box pushed into that face right in front of the
// ball (so the face's triangles nearest the ball are in B's table for the
// small box's sake, the rest are added for the fallback). The ball's
// points get the distance to the nearest face, solve after solve.
TEST(ConsistentDepth, FallbackSearchesTheWholeSurface) {
  TestScene scene;
  int box = scene.Add("box:size=0.2,0.2,0.2:res=8", {0, 0, 0});
  int ball = scene.Add("sphere:size=0.03:res=2", {0.15, 0.004, -0.003});
  int poker = scene.Add("box:size=0.05,0.05,0.05:res=2", {0.24, 0.0, 0.0});
  PenetrationSolver solver;
  for (int solve = 0; solve < 2; ++solve) {
    solver.Solve(scene.objects);
    int fallback = 0, poked = 0;
    for (const PenetrationResult& r : solver.results()) {
      if (r.penetrated != box) continue;  // (the box's face inside the small box)
      if (r.object == poker) {
        ++poked;
        continue;
      }
      ASSERT_EQ(r.object, ball);
      EXPECT_EQ(r.source, DepthSource::kFallback);
      const Eigen::Vector3d p = scene.positions[ball]->row(r.vertex);
      EXPECT_NEAR(r.depth, (Eigen::Vector3d::Constant(0.2) - p.cwiseAbs()).minCoeff(), 1e-12);
      ++fallback;
    }
    EXPECT_EQ(fallback, scene.meshes[ball]->num_vertices());
    EXPECT_GT(poked, 0);
  }
}

TEST(ConsistentDepth, SelfCollisionOnAndOff) {
  // fold a bar: move its last layer of vertices into its middle
  TetMesh bar = TetMesh::Build(MakeShape("box:size=0.2,0.02,0.02:res=10,1,1"));
  Positions folded = bar.positions();
  for (Eigen::Index v = 0; v < folded.rows(); ++v) {
    if (folded(v, 0) > 0.19) folded(v, 0) = -0.03;  // deep inside the bar's middle
  }
  for (bool self : {false, true}) {
    CollisionObject object{&bar, &folded, false, self};
    PenetrationSolver solver;
    const auto& results = solver.Solve(std::span<const CollisionObject>(&object, 1));
    if (!self) {
      EXPECT_TRUE(results.empty());
      continue;
    }
    ASSERT_FALSE(results.empty());
    for (const PenetrationResult& r : results) {
      EXPECT_EQ(r.penetrated, 0);
      EXPECT_TRUE(std::isfinite(r.depth));
      EXPECT_NEAR(r.direction.norm(), 1.0, 1e-9);
      EXPECT_FALSE((bar.tets().row(r.tet).array() == r.vertex).any());
    }
  }
}

TEST(ConsistentDepth, RigidObjectsPenetrateAndArePenetratedButNotEachOther) {
  TestScene scene;
  int soft = scene.Add("sphere:size=0.05:res=2", {0, 0, 0});
  int rigid = scene.Add("box:size=0.03,0.03,0.03:res=3", {0.06, 0, 0}, /*rigid=*/true);
  int rigid2 = scene.Add("box:size=0.03,0.03,0.03:res=3", {0.08, 0, 0}, /*rigid=*/true);
  PenetrationSolver solver;
  solver.Solve(scene.objects);
  int soft_in_rigid = 0, rigid_in_soft = 0;
  for (const PenetrationResult& r : solver.results()) {
    EXPECT_FALSE(scene.objects[r.object].rigid && scene.objects[r.penetrated].rigid);
    soft_in_rigid += r.object == soft && (r.penetrated == rigid || r.penetrated == rigid2);
    rigid_in_soft += (r.object == rigid || r.object == rigid2) && r.penetrated == soft;
  }
  EXPECT_GT(soft_in_rigid, 0);
  EXPECT_GT(rigid_in_soft, 0);
}

TEST(ConsistentDepth, DegenerateConfigurationsGiveFiniteValues) {
  // vertices exactly on faces, edges through triangle edges and vertices,
  // coincident vertices: grid-aligned boxes sharing planes and vertices
  TestScene scene;
  scene.Add("box:size=0.1,0.1,0.1:res=2", {0, 0, 0});
  scene.Add("box:size=0.05,0.05,0.05:res=1", {0.1, 0.1, 0.1});    // corner on corner
  scene.Add("box:size=0.05,0.05,0.05:res=2", {0.0, 0.0, 0.125});  // face planes shared
  scene.Add("sphere:size=0.05:res=0", {-0.1, 0.0, 0.0});          // centre on a face
  for (DepthMethod method : {DepthMethod::kConsistent, DepthMethod::kClosest}) {
    PenetrationOptions options;
    options.method = method;
    PenetrationSolver solver(options);
    solver.Solve(scene.objects);
    EXPECT_FALSE(solver.results().empty());
    for (const PenetrationResult& r : solver.results()) {
      EXPECT_TRUE(std::isfinite(r.depth) && r.depth >= 0.0);
      EXPECT_NEAR(r.direction.norm(), 1.0, 1e-9);
      EXPECT_TRUE(r.barycentric.allFinite());
    }
  }
}

// The closest features against brute force: a torus and a ball in each
// other (each searched through its box tree), and a coarse box's corner in
// a fine ball (the ball has one query: searched whole).
TEST(ClosestFeature, AcceleratedSearchMatchesBruteForce) {
  for (int trial = 0; trial < 2; ++trial) {
    TestScene scene;
    if (trial == 0) {
      scene.Add("torus:size=0.06,0.025:res=3", {0, 0, 0});
      scene.Add("sphere:size=0.04:res=2", {0.05, 0.01, 0.0});
    } else {
      scene.Add("box:size=0.5,0.5,0.5:res=1", {0, 0, 0});
      scene.Add("sphere:size=0.02:res=3", {0.51, 0.505, 0.503});
    }
    PenetrationOptions options;
    options.method = DepthMethod::kClosest;
    PenetrationSolver solver(options);
    solver.Solve(scene.objects);
    ASSERT_FALSE(solver.results().empty());
    for (const PenetrationResult& r : solver.results()) {
      const CollisionObject& b = scene.objects[r.penetrated];
      Eigen::Vector3d p = scene.objects[r.object].positions->row(r.vertex);
      double best = 1e300;
      for (Eigen::Index f = 0; f < b.mesh->surface().rows(); ++f) {
        Eigen::Vector3d c = ClosestPointOnTriangle(p, b.positions->row(b.mesh->surface()(f, 0)),
                                                   b.positions->row(b.mesh->surface()(f, 1)),
                                                   b.positions->row(b.mesh->surface()(f, 2)));
        best = std::min(best, (c - p).norm());
      }
      EXPECT_NEAR(r.depth, best, 1e-15);
      EXPECT_EQ(r.source, DepthSource::kClosest);
    }
  }
}

// The same results bit for bit (what: the run compared, for messages).
void ExpectSameResults(const std::vector<PenetrationResult>& expected,
                       const std::vector<PenetrationResult>& actual, const std::string& what) {
  ASSERT_EQ(expected.size(), actual.size()) << what;
  for (size_t i = 0; i < actual.size(); ++i) {
    const auto& x = expected[i];
    const auto& y = actual[i];
    EXPECT_EQ(std::tie(x.object, x.vertex, x.penetrated, x.tet),
              std::tie(y.object, y.vertex, y.penetrated, y.tet))
        << what;
    EXPECT_TRUE(SameBits({&x.depth, 1}, {&y.depth, 1})) << what;
    EXPECT_TRUE(SameBits({x.direction.data(), 3}, {y.direction.data(), 3})) << what;
    EXPECT_EQ(x.source, y.source) << what;
  }
}

// the solver's results with 1, 2 and 3 threads: the same, bit for bit (3:
// more threads than cores here, and than the groups of some loops)
void ExpectSameResultsWhateverTheThreads(const TestScene& scene, size_t min_results) {
  for (DepthMethod method : {DepthMethod::kConsistent, DepthMethod::kClosest}) {
    std::vector<PenetrationResult> runs[3];
    PenetrationStats stats[3];
    for (int threads : {1, 2, 3}) {
      PenetrationOptions options;
      options.method = method;
      options.num_threads = threads;
      PenetrationSolver solver(options);
      runs[threads - 1] = solver.Solve(scene.objects);
      stats[threads - 1] = solver.stats();
    }
    ASSERT_GT(runs[0].size(), min_results);
    for (int threads : {2, 3}) {
      ExpectSameResults(runs[0], runs[threads - 1], std::to_string(threads) + " threads");
      // the same work, split differently
      const PenetrationStats& split = stats[threads - 1];
      EXPECT_EQ(split.tet_tests, stats[0].tet_tests) << threads << " threads";
      EXPECT_EQ(split.intersection_edges, stats[0].intersection_edges) << threads << " threads";
      EXPECT_EQ(split.triangle_tests, stats[0].triangle_tests) << threads << " threads";
    }
  }
}

TEST(Determinism, SameResultsWhateverTheThreads) {
  // a pile of small spheres (each with many partners)
  TestScene spheres;
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> offset(-0.05, 0.05);
  for (int k = 0; k < 12; ++k) {
    spheres.Add(TetMesh::Build(MakeShape("sphere:size=0.04:res=1")),
                Pose({offset(rng), offset(rng), offset(rng)}, offset(rng) * 30, {1, 2, 3}));
  }
  ExpectSameResultsWhateverTheThreads(spheres, 100);
  // two wide slabs two vertex layers into each other: large enough that
  // every stage (the vertex pass, stages 2 and 3, each propagation layer)
  // runs on all threads
  TestScene slabs;
  const char* slab = "box:size=0.1,0.1,0.02:res=32,32,4";
  slabs.Add(TetMesh::Build(MakeShape(slab)), Pose({0, 0, 0}));
  slabs.Add(TetMesh::Build(MakeShape(slab)), Pose({0.001, 0.002, 0.0215}, 0.01, {1, 2, 3}));
  ExpectSameResultsWhateverTheThreads(slabs, 3500);
  // two fine cubes far into each other: over 16384 vertices to hash, which
  // several threads hash at once (SpatialHash::BuildInsertions), one thread
  // one by one
  TestScene cubes;
  cubes.Add(TetMesh::Build(MakeShape("box:size=0.05:res=30")), Pose({0, 0, 0}));
  cubes.Add(TetMesh::Build(MakeShape("box:size=0.05:res=30")),
            Pose({0.04, 0.003, -0.002}, 0.05, {1, 2, 3}));
  ExpectSameResultsWhateverTheThreads(cubes, 10000);
  // a fine box sunk into a coarse one: large tetrahedra (over 512 cells)
  // looked up through the coarse grid, which is built from over 16384
  // hashed vertices too
  TestScene sunk;
  sunk.Add(TetMesh::Build(MakeShape("box:size=0.2,0.2,0.1:res=8,8,4")), Pose({0, 0, 0}),
           /*rigid=*/true);
  sunk.Add(TetMesh::Build(MakeShape("box:size=0.05:res=30")), Pose({0.01, 0.02, 0.08}));
  ExpectSameResultsWhateverTheThreads(sunk, 10000);
  // a sphere deep in a cube: most of its points get fallback values, from
  // triangles hashed after stage 4; on several threads the surfaces are
  // made in the same parallel region as stage 1, so this checks that
  // region's set-up too, on a first solve
  TestScene enclosed;
  enclosed.Add(TetMesh::Build(MakeShape("sphere:size=0.03:res=2")), Pose({0, 0, 0}));
  enclosed.Add(TetMesh::Build(MakeShape("box:size=0.05,0.05,0.05:res=5,5,10:split=5")),
               Pose({0.01, 0, 0}));
  PenetrationSolver solver;
  int fallback = 0;
  for (const PenetrationResult& result : solver.Solve(enclosed.objects)) {
    fallback += result.source == DepthSource::kFallback;
  }
  EXPECT_GT(fallback, 100);
  ExpectSameResultsWhateverTheThreads(enclosed, 300);
  // a self-colliding slab whose far half is folded back into its near half,
  // and a rigid box pressed into it: self hits and hits in a rigid object
  TestScene folded;
  TetMesh slab_mesh = TetMesh::Build(MakeShape("box:size=0.1,0.02,0.02:res=40,8,8"));
  const int slab_object = folded.Add(std::move(slab_mesh), Pose({0, 0, 0}), /*rigid=*/false,
                                     /*self_collision=*/true);
  Positions& x = *folded.positions[slab_object];
  for (Eigen::Index v = 0; v < x.rows(); ++v) {
    if (x(v, 0) > 0.0) x.row(v) += Eigen::RowVector3d(-0.045, 0.003, 0.004);
  }
  folded.Add(TetMesh::Build(MakeShape("box:size=0.03,0.03,0.03:res=6,6,6")),
             Pose({-0.03, 0, 0.022}), /*rigid=*/true);
  int self_hits = 0, rigid_hits = 0;
  for (const PenetrationResult& result : solver.Solve(folded.objects)) {
    self_hits += result.object == slab_object && result.penetrated == slab_object;
    rigid_hits += result.penetrated != slab_object;
  }
  EXPECT_GT(self_hits, 100);
  EXPECT_GT(rigid_hits, 20);
  ExpectSameResultsWhateverTheThreads(folded, 200);
}

// A solver keeps its buffers from solve to solve (stamps, tables, the
// small bodies' triangle groups, whose last lanes must not keep another
// body's triangles): one solver taken through different scenes, one after
// another, gives what a new solver gives on each, bit for bit.
TEST(Determinism, ReusedSolverMatchesANewOne) {
  std::vector<TestScene> scenes;
  for (int trial : {0, 1, 2, 3, 0}) scenes.push_back(CrowdedScene(trial));
  TestScene fewer;  // the first crowded scene without its first three bodies
  const TestScene& first = scenes[0];
  for (size_t o = 0; o < first.objects.size(); ++o) {
    if (o >= 1 && o <= 3) continue;
    fewer.Add(TetMesh(*first.objects[o].mesh), Pose({0, 0, 0}), first.objects[o].rigid,
              first.objects[o].self_collision);
    *fewer.positions.back() = *first.objects[o].positions;
  }
  scenes.push_back(std::move(fewer));
  // a box pushed into a small box, then into a bipyramid in its place: the
  // bipyramid's 6 triangles take the slots of the small box's first 8, of
  // which 6 and 7 are its side at x = 0.035, beyond the bipyramid and
  // crossed by the pushed box's edges
  for (bool small_box : {true, false}) {
    TestScene scene;
    scene.Add(TetMesh::Build(small_box ? MakeShape("box:size=0.035:res=1") : Bipyramid(0.03, 0.03)),
              Pose({0, 0, 0}));
    scene.Add(TetMesh::Build(MakeShape("box:size=0.02:res=2")), Pose({0.02, 0.004, 0.003}));
    scenes.push_back(std::move(scene));
  }
  for (DepthMethod method : {DepthMethod::kConsistent, DepthMethod::kClosest}) {
    for (int threads : {1, 2}) {
      PenetrationOptions options;
      options.method = method;
      options.num_threads = threads;
      PenetrationSolver reused(options);
      for (size_t i = 0; i < scenes.size(); ++i) {
        const std::vector<PenetrationResult> results = reused.Solve(scenes[i].objects);
        PenetrationSolver fresh(options);
        ASSERT_FALSE(results.empty());
        ExpectSameResults(fresh.Solve(scenes[i].objects), results,
                          std::string(DepthMethodName(method)) + ", " + std::to_string(threads) +
                              " threads, scene " + std::to_string(i));
      }
    }
  }
}

// A fixed object (CollisionObject::fixed) is solved from what the solver
// kept of it (its box, a tree over its chunks of tets and their faces),
// passing over the parts far from its partners. Its results must be those
// of the same scene solved without the flag, bit for bit, solve after
// solve while the other objects move into it, across it and out, for both
// methods on one and two threads. An object flagged fixed that moves
// anyway (`moved_at`: shifted in place before that solve) must be seen to
// move and solved as not fixed, then kept again.
//
// Framed (CollisionObject::frame): the kept objects turn and move rigidly
// instead, their positions the frame applied to their first ones, and the
// same holds; at `moved_at` they are shifted without their frame saying so.
// Framed with bounds: the frames also carry the box of the positions
// (RigidFrame::bounds), as the bridge gives them, so that the solver does
// not pass over the positions for it.
enum class Kept { kFixed, kFramed, kFramedWithBounds };

void ExpectKeptSolvedAsNotKept(TestScene& scene, const std::vector<int>& kept, int min_results,
                               int moved_at = -1, Kept how = Kept::kFixed) {
  constexpr int kSolves = 8;
  std::vector<CollisionObject> flagged = scene.objects;
  std::vector<RigidFrame> frames(scene.objects.size());
  for (int o : kept) {
    flagged[o].fixed = how == Kept::kFixed;
    if (how != Kept::kFixed) flagged[o].frame = &frames[o];
  }
  const std::vector<Positions> start = [&] {
    std::vector<Positions> x;
    for (const auto& positions : scene.positions) x.push_back(*positions);
    return x;
  }();
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> speed(-0.004, 0.004);  // metres a solve
  std::vector<Eigen::RowVector3d> velocity;
  std::vector<Eigen::Vector3d> axis;
  for (size_t o = 0; o < scene.objects.size(); ++o) {
    velocity.emplace_back(speed(rng), speed(rng), speed(rng));
  }
  for (size_t o = 0; o < scene.objects.size(); ++o) {
    axis.push_back(Eigen::Vector3d(speed(rng), speed(rng), speed(rng)).normalized());
  }
  for (DepthMethod method : {DepthMethod::kConsistent, DepthMethod::kClosest}) {
    for (int threads : {1, 2}) {
      PenetrationOptions options;
      options.method = method;
      options.num_threads = threads;
      PenetrationSolver with_flag(options), without(options);
      int results = 0;
      for (size_t o = 0; o < scene.objects.size(); ++o) *scene.positions[o] = start[o];
      for (int solve = 0; solve < kSolves; ++solve) {
        const std::string what = std::string(DepthMethodName(method)) + ", " +
                                 std::to_string(threads) + " threads, solve " +
                                 std::to_string(solve);
        for (size_t o = 0; o < scene.objects.size(); ++o) {
          const bool is_kept = std::find(kept.begin(), kept.end(), o) != kept.end();
          if (!is_kept) {
            *scene.positions[o] = start[o].rowwise() + velocity[o] * solve;
          } else if (how == Kept::kFixed) {
            *scene.positions[o] = start[o];  // (back in place after moved_at)
          } else {
            // turning about its first centroid (0.01 rad a solve) as it moves
            const Eigen::Vector3d centre = start[o].colwise().mean().transpose();
            RigidFrame& frame = frames[o];
            frame.rotation = Eigen::AngleAxisd(0.01 * solve, axis[o]).toRotationMatrix();
            frame.translation = centre - frame.rotation * centre + velocity[o].transpose() * solve;
            *scene.positions[o] =
                (start[o] * frame.rotation.transpose()).rowwise() + frame.translation.transpose();
          }
        }
        const int moved = solve == moved_at || (moved_at >= 0 && solve == moved_at + 1);
        if (solve == moved_at) *scene.positions[kept[0]] = scene.positions[kept[0]]->array() + 1e-4;
        if (how == Kept::kFramedWithBounds) {
          for (int o : kept) frames[o].bounds = PositionBounds::Of(*scene.positions[o]);
        }
        const std::vector<PenetrationResult> expected = without.Solve(scene.objects);
        ExpectSameResults(expected, with_flag.Solve(flagged), what);
        const int num_kept = static_cast<int>(kept.size()) - moved;
        EXPECT_EQ(with_flag.stats().fixed_objects, how == Kept::kFixed ? num_kept : 0) << what;
        EXPECT_EQ(with_flag.stats().framed_objects, how == Kept::kFixed ? 0 : num_kept) << what;
        EXPECT_EQ(without.stats().fixed_objects + without.stats().framed_objects, 0) << what;
        results += static_cast<int>(expected.size());
      }
      EXPECT_GT(results, min_results) << DepthMethodName(method) << ", " << threads;
      for (size_t o = 0; o < scene.objects.size(); ++o) *scene.positions[o] = start[o];
    }
  }
}

void ExpectKeptSolvedAsNotKept(Kept how) {
  {
    SCOPED_TRACE("bodies on a fine slab");
    TestScene scene;
    scene.Add(TetMesh::Build(MakeShape("box:size=0.2,0.2,0.01:res=40,40,2")), Pose({0, 0, 0}),
              /*rigid=*/true);
    const char* shapes[] = {"sphere:size=0.02:res=1", "box:size=0.015,0.02,0.01:res=3",
                            "capsule:size=0.008,0.015:res=2", "torus:size=0.02,0.008:res=2"};
    std::mt19937 rng(3);
    std::uniform_real_distribution<double> across(-0.15, 0.15);
    for (int k = 0; k < 8; ++k) {
      scene.Add(TetMesh::Build(MakeShape(shapes[k % 4])),
                Pose({across(rng), across(rng), 0.012 + 0.004 * (k % 3)}, 0.3 * k, {1, 2, 3}));
    }
    scene.Add("sphere:size=0.01:res=1", {0.05, 0.05, 0.0});  // deep in it: fallback values
    scene.Add("sphere:size=0.02:res=1", {0.5, 0.5, 0.5});    // far from it
    ExpectKeptSolvedAsNotKept(scene, {0}, 1500, /*moved_at=*/4, how);
  }
  for (int trial : {0, 1}) {
    SCOPED_TRACE("crowded scene " + std::to_string(trial));  // (its box: rigid in trial 1)
    TestScene scene = CrowdedScene(trial);
    ExpectKeptSolvedAsNotKept(scene, {0}, 500, -1, how);
  }
  {
    SCOPED_TRACE("a fixed self-colliding slab folded into itself, and two fixed bodies");
    TestScene scene;
    const int slab =
        scene.Add(TetMesh::Build(MakeShape("box:size=0.1,0.02,0.02:res=40,8,8")), Pose({0, 0, 0}),
                  /*rigid=*/false, /*self_collision=*/true);
    Positions& x = *scene.positions[slab];
    for (Eigen::Index v = 0; v < x.rows(); ++v) {
      if (x(v, 0) > 0.0) x.row(v) += Eigen::RowVector3d(-0.045, 0.003, 0.004);
    }
    scene.Add(TetMesh::Build(MakeShape("box:size=0.03,0.03,0.03:res=6,6,6")),
              Pose({-0.03, 0, 0.022}), /*rigid=*/true);
    scene.Add("sphere:size=0.02:res=2", {0.0, 0.0, -0.02});
    ExpectKeptSolvedAsNotKept(scene, {slab, 2}, 1000, -1, how);
  }
  {
    SCOPED_TRACE("a fixed body with vertices in no tetrahedron");
    RawMesh raw = MakeShape("box:size=0.05,0.05,0.01:res=10,10,2");
    const Eigen::Index n = raw.positions.rows();
    raw.positions.conservativeResize(n + 2, 3);
    raw.positions.row(n) << 0.0, 0.0, 0.03;      // inside the ball above
    raw.positions.row(n + 1) << 0.04, 0.0, 0.0;  // beside the box
    TetMeshOptions options;
    options.drop_unreferenced = false;
    TestScene scene;
    scene.Add(TetMesh::Build(std::move(raw), options), Pose({0, 0, 0}), /*rigid=*/true);
    ASSERT_EQ(scene.meshes[0]->num_vertices(), n + 2);
    scene.Add("sphere:size=0.02:res=2", {0.0, 0.0, 0.025});
    ExpectKeptSolvedAsNotKept(scene, {0}, 20, -1, how);
    PenetrationSolver solver;
    std::vector<CollisionObject> flagged = scene.objects;
    const RigidFrame identity;
    flagged[0].fixed = how == Kept::kFixed;
    if (how == Kept::kFramed) flagged[0].frame = &identity;
    bool loose_found = false;
    for (const PenetrationResult& r : solver.Solve(flagged)) {
      loose_found |= r.object == 0 && r.vertex == n;
    }
    EXPECT_TRUE(loose_found);
  }
}

TEST(FixedObjects, SameResultsAsNotFixed) {
  ExpectKeptSolvedAsNotKept(Kept::kFixed);
}

TEST(FramedObjects, SameResultsAsWithoutFrame) {
  ExpectKeptSolvedAsNotKept(Kept::kFramed);
}

TEST(FramedObjects, SameResultsWithTheBoxGiven) {
  ExpectKeptSolvedAsNotKept(Kept::kFramedWithBounds);
}

// PositionBounds against the box and finiteness computed coordinate by
// coordinate; given as RigidFrame::bounds, a box of other positions (kept
// from before a move, or of a vertex gone to infinity) is a clear error,
// and bounds of positions that are not all finite leave the object out, as
// the solver's own pass does.
TEST(FramedObjects, GivenBoxIsCheckedAndNonFiniteLeftOut) {
  TestScene scene;
  scene.Add(TetMesh::Build(MakeShape("box:size=0.1,0.1,0.02:res=10,10,2")), Pose({0, 0, 0}),
            /*rigid=*/true);
  scene.Add("sphere:size=0.02:res=2", {0.01, 0.02, 0.03});
  const Positions& x = *scene.positions[0];
  const PositionBounds bounds = PositionBounds::Of(x);
  EXPECT_TRUE(bounds.finite());
  for (int k = 0; k < 3; ++k) {
    EXPECT_EQ(bounds.lo[k], x.col(k).minCoeff());
    EXPECT_EQ(bounds.hi[k], x.col(k).maxCoeff());
  }
  RigidFrame frame;
  frame.bounds = bounds;
  std::vector<CollisionObject> framed = scene.objects;
  framed[0].frame = &frame;
  PenetrationSolver solver, without;
  ExpectSameResults(without.Solve(scene.objects), solver.Solve(framed), "as given");
  ASSERT_GT(solver.results().size(), 10u);
  // moved, the box not
  *scene.positions[0] = scene.positions[0]->array() + 0.01;
  try {
    solver.Solve(framed);
    ADD_FAILURE() << "a box of other positions was taken";
  } catch (const Error& error) {
    const std::string message = error.what();
    EXPECT_NE(message.find("object 0"), std::string::npos) << message;
    EXPECT_NE(message.find("RigidFrame::bounds"), std::string::npos) << message;
  }
  frame.bounds = PositionBounds::Of(*scene.positions[0]);
  ExpectSameResults(without.Solve(scene.objects), solver.Solve(framed), "moved, box again");
  // the last vertex at infinity: the given box must say so, and the object
  // is left out
  (*scene.positions[0])(x.rows() - 1, 2) = std::numeric_limits<double>::infinity();
  EXPECT_THROW(solver.Solve(framed), Error);
  frame.bounds = PositionBounds::Of(*scene.positions[0]);
  EXPECT_FALSE(frame.bounds->finite());
  ExpectSameResults(without.Solve(scene.objects), solver.Solve(framed), "not finite");
  EXPECT_EQ(solver.stats().non_finite_objects, 1);
  EXPECT_EQ(without.stats().non_finite_objects, 1);
}

// A framed body carried far from where it was kept (the rounding of its
// positions grows with their magnitude, and it is kept anew), then given a
// frame that is not a rotation (a scaled one: the frame is not used), is
// solved as without its frame, bit for bit.
TEST(FramedObjects, CarriedFarAndNotARotation) {
  TestScene scene;
  scene.Add(TetMesh::Build(MakeShape("box:size=0.1,0.1,0.02:res=20,20,4")), Pose({0, 0, 0}),
            /*rigid=*/true);
  scene.Add("sphere:size=0.02:res=2", {0.01, 0.02, 0.03});
  std::vector<Positions> start;
  for (const auto& x : scene.positions) start.push_back(*x);
  RigidFrame frame;
  std::vector<CollisionObject> framed = scene.objects;
  framed[0].frame = &frame;
  PenetrationSolver with_frame, without;
  const double far[] = {0.0, 1.0, 1e3, 1e3, 1e6, 1e6, 0.0};
  for (int solve = 0; solve < static_cast<int>(std::size(far)); ++solve) {
    frame.rotation =
        Eigen::AngleAxisd(0.3 * solve, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
    frame.translation = Eigen::Vector3d(1.0, -2.0, 0.5) * far[solve];
    for (int o : {0, 1}) {
      *scene.positions[o] =
          (start[o] * frame.rotation.transpose()).rowwise() + frame.translation.transpose();
    }
    const std::vector<PenetrationResult> expected = without.Solve(scene.objects);
    ASSERT_GT(expected.size(), 10u);
    ExpectSameResults(expected, with_frame.Solve(framed), "solve " + std::to_string(solve));
    EXPECT_EQ(with_frame.stats().framed_objects, 1) << solve;
  }
  frame.rotation *= 1.01;  // (positions as they were: only the frame is wrong)
  const std::vector<PenetrationResult> expected = without.Solve(scene.objects);
  ExpectSameResults(expected, with_frame.Solve(framed), "scaled frame");
  EXPECT_EQ(with_frame.stats().framed_objects, 0);
}

// A ball that pokes through the top face of a fixed box and then is
// enclosed deep in it, in one jump or sinking step by step: enclosed, its
// points get fallback values from the box's nearest faces, those it had
// poked through before. After the jump, no chunk near them is searched, and
// their corners' outcodes of the earlier solve must not pass for this
// solve's (the test fails if they are left as they were).
TEST(FixedObjects, BallSinkingIntoAFixedBoxMatchesNotFixed) {
  TestScene scene;
  scene.Add(TetMesh::Build(MakeShape("box:size=0.05:res=10")), Pose({0, 0, 0}), /*rigid=*/true);
  const int ball = scene.Add("sphere:size=0.01:res=1", {0.003, 0.002, 0.05});
  const Positions start = *scene.positions[ball];
  std::vector<CollisionObject> flagged = scene.objects;
  flagged[0].fixed = true;
  PenetrationSolver with_flag, without;
  int fallback = 0;
  const double sunk[] = {0.0, 0.035, 0.0, 0.035, 0.005, 0.01, 0.015, 0.02, 0.025, 0.03, 0.035};
  for (int solve = 0; solve < static_cast<int>(std::size(sunk)); ++solve) {
    *scene.positions[ball] = start.rowwise() - Eigen::RowVector3d(0, 0, sunk[solve]);
    const std::vector<PenetrationResult> expected = without.Solve(scene.objects);
    ExpectSameResults(expected, with_flag.Solve(flagged), "solve " + std::to_string(solve));
    EXPECT_EQ(with_flag.stats().fixed_objects, 1);
    fallback += without.stats().fallback;
  }
  EXPECT_GT(fallback, 20);
}

// One solver taken through different scenes whose first object is fixed
// (what it kept of one object must not pass for another's in its place):
// the results of a new solver without the flag on each, bit for bit.
TEST(FixedObjects, ReusedSolverMatchesANewOne) {
  std::vector<TestScene> scenes;
  auto slab_scene = [] {
    TestScene scene;
    scene.Add(TetMesh::Build(MakeShape("box:size=0.1,0.1,0.03:res=20,20,6")), Pose({0, 0, 0}),
              /*rigid=*/true);
    scene.Add("sphere:size=0.01:res=1", {0.02, 0.0, 0.0});  // enclosed: fallback values
    scene.Add("box:size=0.02:res=3", {-0.05, 0.03, 0.035});
    return scene;
  };
  scenes.push_back(slab_scene());
  scenes.push_back(CrowdedScene(0));
  scenes.push_back(slab_scene());
  scenes.push_back(CrowdedScene(1));
  scenes.push_back(slab_scene());
  for (int threads : {1, 2}) {
    PenetrationOptions options;
    options.num_threads = threads;
    PenetrationSolver reused(options);
    for (size_t i = 0; i < scenes.size(); ++i) {
      std::vector<CollisionObject> flagged = scenes[i].objects;
      flagged[0].fixed = true;
      const std::vector<PenetrationResult> results = reused.Solve(flagged);
      EXPECT_EQ(reused.stats().fixed_objects, 1);
      if (i == 0) {
        EXPECT_GT(reused.stats().fallback, 0);
      }
      ASSERT_FALSE(results.empty());
      PenetrationSolver fresh(options);
      ExpectSameResults(fresh.Solve(scenes[i].objects), results,
                        std::to_string(threads) + " threads, scene " + std::to_string(i));
    }
  }
}

// The cell size is a speed setting: whatever it is (from a fortieth of
// the average edge to ten million times it), the results are the same,
// bit for bit, as with the default. (Tolerances such as "on the surface"
// go with the scene's edges, not with the cell: a huge cell once made every
// crossing count as on the surface, and every border depth 0.)
TEST(Determinism, SameResultsWhateverTheCellSize) {
  TestScene cubes;  // deep: border and propagated points
  cubes.Add("box:size=0.04:res=5", {0, 0, 0});
  cubes.Add("box:size=0.04:res=4", {0.05, 0.004, -0.003});
  std::vector<const TestScene*> scenes = {&cubes};
  TestScene crowded = CrowdedScene(1);  // self-collision, rigid bodies, small bodies
  scenes.push_back(&crowded);
  for (const TestScene* scene : scenes) {
    for (DepthMethod method : {DepthMethod::kConsistent, DepthMethod::kClosest}) {
      PenetrationOptions options;
      options.method = method;
      PenetrationSolver reference(options);
      const std::vector<PenetrationResult> expected = reference.Solve(scene->objects);
      ASSERT_GT(expected.size(), 50u);
      int border = 0;
      for (const PenetrationResult& r : expected) border += r.source == DepthSource::kBorder;
      if (method == DepthMethod::kConsistent) {
        ASSERT_GT(border, 20);
      }
      const double edge = reference.length_scale();
      for (double factor : {0.025, 0.3, 3.0, 1e7}) {
        options.cell_size = factor * edge;
        PenetrationSolver solver(options);
        ExpectSameResults(expected, solver.Solve(scene->objects),
                          std::string(DepthMethodName(method)) + ", cell " +
                              std::to_string(factor) + " times the average edge");
      }
    }
  }
}

// A cell size that is negative, infinite or NaN is an error that says so,
// from the constructor and from set_options, which then keeps the old
// options.
TEST(Determinism, BadCellSizeIsAClearError) {
  for (double bad :
       {-0.01, std::numeric_limits<double>::infinity(), std::numeric_limits<double>::quiet_NaN()}) {
    SCOPED_TRACE(bad);
    PenetrationOptions options;
    options.cell_size = bad;
    try {
      PenetrationSolver solver(options);
      ADD_FAILURE() << "no error";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("cell size"), std::string::npos) << e.what();
    }
    PenetrationSolver solver;
    EXPECT_THROW(solver.set_options(options), Error);
    EXPECT_EQ(solver.options().cell_size, 0.0);
  }
}

// An object whose positions do not match its mesh (or that has neither) is
// an error that names it, not a read past the end.
TEST(Determinism, MismatchedObjectIsAClearError) {
  TestScene scene;
  scene.Add("box:size=0.05:res=2", {0, 0, 0});
  scene.Add("box:size=0.05:res=2", {0.05, 0, 0});
  const Positions fewer = scene.positions[1]->topRows(5);
  std::vector<CollisionObject> objects = scene.objects;
  objects[1].positions = &fewer;
  PenetrationSolver solver;
  try {
    solver.Solve(objects);
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("object 1 has 5 positions for a mesh of 27 vertices"),
              std::string::npos)
        << e.what();
  }
  objects[1].positions = nullptr;
  EXPECT_THROW(solver.Solve(objects), Error);
  // and the solver still works after
  EXPECT_GT(solver.Solve(scene.objects).size(), 0u);
}

}  // namespace
}  // namespace tetcosim
