#include "collision/kept_object.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <random>
#include <string>
#include <vector>

#include "collision/penetration.h"
#include "tests/collision/scene_helpers.h"

namespace tetcosim {
namespace {

using testing::CrowdedScene;
using testing::ExpectSameResults;
using testing::Pose;
using testing::TestScene;

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

}  // namespace
}  // namespace tetcosim
