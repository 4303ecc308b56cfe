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

using testing::Bipyramid;
using testing::CrowdedScene;
using testing::Pose;
using testing::TestScene;

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
