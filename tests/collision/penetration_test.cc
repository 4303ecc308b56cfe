#include "collision/penetration.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <random>
#include <string>

#include "collision/geometry.h"
#include "mesh/error.h"
#include "tests/collision/scene_helpers.h"

namespace tetcosim {
namespace {

using testing::Bipyramid;
using testing::CrowdedScene;
using testing::ExpectSameResults;
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
