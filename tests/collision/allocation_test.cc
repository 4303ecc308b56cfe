// The penetration solver allocates no memory once warm (the collision
// issue: buffers are reused from step to step). tests/support/
// allocation_counter.h counts the allocations: malloc and its kin, or
// under the sanitizers every form of operator new, the aligned ones too (a
// vector of an over-aligned type, a struct with an Eigen::Vector4d aligned
// to 32 bytes in the x86-64-v3 build as stage 1's hits, allocates through
// those, which this test did not count before session 48).

#include <gtest/gtest.h>
#include <omp.h>

#include <algorithm>
#include <atomic>
#include <tuple>
#include <vector>

#include "collision/penetration.h"
#include "tests/collision/scene_helpers.h"
#include "tests/support/allocation_counter.h"

namespace tetcosim {
namespace {

// solve(), with OpenMP's parallel regions made inactive if `whole`
// (omp_set_max_active_levels(0)): a solver for two threads then runs every
// loop on the calling thread alone, with its buffers for two. That is the
// largest share of the work a thread can get, made certain; shared by two
// threads, the shares vary from solve to solve. (Stage 2 lists a point's
// neighbours inside as candidates and takes them back when the point is
// not a border point: a thread's list can briefly hold more than all the
// points' together.) The tests warm a solver for two threads whole, so
// that the other thread's buffers are still empty when it first gets work.
template <typename Solve>
void SolveWholeOnOneThreadIf(bool whole, const Solve& solve) {
  const int max_active_levels = omp_get_max_active_levels();
  if (whole) omp_set_max_active_levels(0);
  solve();
  omp_set_max_active_levels(max_active_levels);
}

// The allocations of SolveWholeOnOneThreadIf(whole, solve): taken whole,
// operator new's only (OpenMP's runtime, libgomp, mallocs a team for
// every region it runs inactive: the test's doing, not the solver's).
// OpenMP's threads are started first (a solver warmed whole has not
// started them yet; their start allocates).
template <typename Solve>
long AllocationsOf(bool whole, const Solve& solve) {
  std::atomic<int> started = 0;  // (a region with no work is left out by the compiler)
#pragma omp parallel num_threads(2)
  started.fetch_add(1, std::memory_order_relaxed);
  const long heap = testing::HeapAllocations();
  const long calls = testing::OperatorNewCalls();
  SolveWholeOnOneThreadIf(whole, solve);
  return whole ? testing::OperatorNewCalls() - calls : testing::HeapAllocations() - heap;
}

// Two overlapping cubes, a ball enclosed in one (closest-feature
// fallback) and a coarse rigid slab under them (triangles too large to
// hash: their box tree): after two solves, further solves of the same
// scene allocate nothing, with either method, at the default cell size
// and at 2 mm cells (where the slab's tetrahedra are too large to search
// cell by cell: the coarser vertex grid). The same with the slab fixed
// (CollisionObject::fixed): what is kept of it is kept on the first solve;
// and with it moving with a frame (CollisionObject::frame). On one thread
// and on two, where the work falls to the threads differently from solve
// to solve (there 100 solves, every other one taken whole by one thread:
// SolveWholeOnOneThreadIf): a thread's buffers are made ready for any share
// before each loop (penetration_internal.h), else a buffer grew whenever a
// thread's share was its largest yet, now and then for hundreds of solves.
TEST(Allocation, WarmSolvesAllocateNothing) {
  testing::TestScene scene;
  scene.Add("box:size=0.05:res=6", {0, 0, 0});
  scene.Add("box:size=0.05:res=6", {0.07, 0.01, 0.0});
  scene.Add("sphere:size=0.03:res=1", {0.0, 0.0, 0.0});
  const int slab = scene.Add("box:size=0.5,0.5,0.05:res=20,20,1", {0, 0, -0.09}, /*rigid=*/true);
  const Positions slab_start = *scene.positions[slab];
  RigidFrame frame;
  enum Slab { kPlain, kFixed, kFramed };
  for (const auto& [method, cell_size, kept, threads] :
       {std::tuple{DepthMethod::kConsistent, 0.0, kPlain, 1},
        std::tuple{DepthMethod::kClosest, 0.0, kPlain, 1},
        std::tuple{DepthMethod::kConsistent, 0.002, kPlain, 1},
        std::tuple{DepthMethod::kConsistent, 0.0, kFixed, 1},
        std::tuple{DepthMethod::kClosest, 0.0, kFramed, 1},
        std::tuple{DepthMethod::kConsistent, 0.0, kPlain, 2},
        std::tuple{DepthMethod::kClosest, 0.0, kPlain, 2},
        std::tuple{DepthMethod::kConsistent, 0.002, kPlain, 2},
        std::tuple{DepthMethod::kConsistent, 0.0, kFixed, 2},
        std::tuple{DepthMethod::kClosest, 0.0, kFramed, 2}}) {
    // (the slab: what is kept of it, kept once)
    scene.objects[slab].fixed = kept == kFixed;
    scene.objects[slab].frame = kept == kFramed ? &frame : nullptr;
    PenetrationOptions options;
    options.method = method;
    options.cell_size = cell_size;
    options.num_threads = threads;
    PenetrationSolver solver(options);
    // (framed: the slab moves up a little every solve)
    // (kept copied in: clang before 16 cannot capture a structured binding)
    auto solve = [&, kept = kept](int k) {
      frame.translation.z() = kept == kFramed ? 1e-4 * k : 0.0;
      *scene.positions[slab] = slab_start.rowwise() + frame.translation.transpose();
      solver.Solve(scene.objects);
    };
    // (warmed whole: on two threads, the second thread has done nothing
    // yet when the shared solves begin)
    for (int k = 0; k < 2; ++k) SolveWholeOnOneThreadIf(threads == 2, [&] { solve(k); });
    // (on two threads, three configurations in turn, shared and whole)
    long allocations = 0;
    for (int k = 2; k < (threads == 1 ? 5 : 102); ++k) {
      allocations += AllocationsOf(threads == 2 && k % 2 == 1, [&] { solve(2 + k % 3); });
    }
    EXPECT_EQ(allocations, 0) << DepthMethodName(method) << " " << cell_size << " " << kept << " "
                              << threads;
    EXPECT_EQ(solver.stats().fixed_objects, kept == kFixed ? 1 : 0);
    EXPECT_EQ(solver.stats().framed_objects, kept == kFramed ? 1 : 0);
    EXPECT_GT(solver.results().size(), 100u);
    if (method == DepthMethod::kConsistent) {
      EXPECT_GT(solver.stats().fallback, 0);
    }
  }
}

// The layer of 576 paper spheres that CollidingPoints.PileInStripsMatchesBruteForce
// checks the broad phase cuts into strips (from 512 objects), settling over
// five solves, its neighbours at different rates (so that contacts deepen
// and buffers may grow): solved over those five steps again, it allocates
// nothing, on one thread and on two (there 50 times, every other one
// taken whole by one thread).
TEST(Allocation, WarmSolvesOfAPileInStripsAllocateNothing) {
  testing::TestScene scene = testing::SphereLayer(24, 13);
  std::vector<Positions> start;
  for (const auto& x : scene.positions) start.push_back(*x);
  for (int threads : {1, 2}) {
    PenetrationOptions options;
    options.num_threads = threads;
    PenetrationSolver solver(options);
    auto solve = [&](int k) {  // (sphere o down by k x 0.1, 0.2 or 0.3 mm, by o % 3)
      for (size_t o = 0; o < start.size(); ++o) {
        *scene.positions[o] = start[o];
        scene.positions[o]->col(2).array() -= 1e-4 * k * static_cast<double>(1 + o % 3);
      }
      solver.Solve(scene.objects);
    };
    for (int k = 0; k < 5; ++k) SolveWholeOnOneThreadIf(threads == 2, [&] { solve(k); });
    // (on two threads, the five steps ten times, shared and whole)
    long allocations = 0;
    for (int k = 0; k < (threads == 1 ? 5 : 50); ++k) {
      allocations += AllocationsOf(threads == 2 && k % 2 == 1, [&] { solve(k % 5); });
    }
    EXPECT_EQ(allocations, 0) << threads << " threads";
    EXPECT_GT(solver.results().size(), 1000u);
  }
}

// The crowded scenes of the determinism tests (CrowdedScene: a box with 14
// bodies of four shapes in and around it, some rigid, and a bar folded
// into itself with self-collision), with either method on two threads:
// after two solves, 100 more allocate nothing, every other one taken whole
// by one thread (SolveWholeOnOneThreadIf). Warmed whole (the other thread
// starts empty), and warmed shared (the first whole solve gives a thread
// more than it has ever held: all the points, and the candidates a point
// lists and takes back).
TEST(Allocation, WarmSolvesOfCrowdedScenesOnTwoThreadsAllocateNothing) {
  for (DepthMethod method : {DepthMethod::kConsistent, DepthMethod::kClosest}) {
    for (const auto& [trial, warm_whole] :
         {std::pair{0, true}, std::pair{1, true}, std::pair{0, false}, std::pair{1, false}}) {
      testing::TestScene scene = testing::CrowdedScene(trial);
      PenetrationOptions options;
      options.method = method;
      options.num_threads = 2;
      PenetrationSolver solver(options);
      for (int k = 0; k < 2; ++k) {
        SolveWholeOnOneThreadIf(warm_whole, [&] { solver.Solve(scene.objects); });
      }
      long allocations = 0;
      for (int k = 0; k < 100; ++k) {
        allocations += AllocationsOf(k % 2 == 1, [&] { solver.Solve(scene.objects); });
      }
      EXPECT_EQ(allocations, 0) << DepthMethodName(method) << " trial " << trial
                                << (warm_whole ? " warmed whole" : "");
      EXPECT_GT(solver.results().size(), 50u);
      EXPECT_TRUE(std::any_of(solver.results().begin(), solver.results().end(),
                              [](const PenetrationResult& r) { return r.object == r.penetrated; }))
          << "the bar is folded into itself";
    }
  }
}

}  // namespace
}  // namespace tetcosim
