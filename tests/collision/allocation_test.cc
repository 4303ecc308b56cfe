// The penetration solver allocates no memory once warm (the collision
// issue: buffers are reused from step to step). Every operator new of this
// test binary is counted.

#include <gtest/gtest.h>

#include <atomic>
#include <cstdlib>
#include <new>
#include <tuple>
#include <vector>

#include "collision/penetration.h"
#include "tests/collision/scene_helpers.h"

namespace {
std::atomic<long> allocations{0};
}  // namespace

void* operator new(std::size_t size) {
  allocations.fetch_add(1, std::memory_order_relaxed);
  if (void* p = std::malloc(size == 0 ? 1 : size)) return p;
  throw std::bad_alloc();
}
// (not inlined: inlined into a caller, GCC pairs the free with its own
// idea of operator new and warns of a mismatch, -Wmismatched-new-delete)
[[gnu::noinline]] void operator delete(void* p) noexcept {
  std::free(p);
}
[[gnu::noinline]] void operator delete(void* p, std::size_t) noexcept {
  std::free(p);
}

namespace tetcosim {
namespace {

// Two overlapping cubes, a ball enclosed in one (closest-feature
// fallback) and a coarse rigid slab under them (triangles too large to
// hash: their box tree): after two solves, further solves of the same
// scene allocate nothing, with either method, at the default cell size
// and at 2 mm cells (where the slab's tetrahedra are too large to search
// cell by cell: the coarser vertex grid). One thread: on several, a
// thread's share of the work varies from solve to solve, and its buffers
// grow until they hold its largest share. The same with the slab fixed
// (CollisionObject::fixed): what is kept of it is kept on the first solve;
// and with it moving with a frame (CollisionObject::frame).
TEST(Allocation, WarmSolvesAllocateNothing) {
  testing::TestScene scene;
  scene.Add("box:size=0.05:res=6", {0, 0, 0});
  scene.Add("box:size=0.05:res=6", {0.07, 0.01, 0.0});
  scene.Add("sphere:size=0.03:res=1", {0.0, 0.0, 0.0});
  const int slab = scene.Add("box:size=0.5,0.5,0.05:res=20,20,1", {0, 0, -0.09}, /*rigid=*/true);
  const Positions slab_start = *scene.positions[slab];
  RigidFrame frame;
  enum Slab { kPlain, kFixed, kFramed };
  for (const auto& [method, cell_size, kept] : {std::tuple{DepthMethod::kConsistent, 0.0, kPlain},
                                                std::tuple{DepthMethod::kClosest, 0.0, kPlain},
                                                std::tuple{DepthMethod::kConsistent, 0.002, kPlain},
                                                std::tuple{DepthMethod::kConsistent, 0.0, kFixed},
                                                std::tuple{DepthMethod::kClosest, 0.0, kFramed}}) {
    // (the slab: what is kept of it, kept once)
    scene.objects[slab].fixed = kept == kFixed;
    scene.objects[slab].frame = kept == kFramed ? &frame : nullptr;
    PenetrationOptions options;
    options.method = method;
    options.cell_size = cell_size;
    options.num_threads = 1;
    PenetrationSolver solver(options);
    // (framed: the slab moves up a little every solve)
    // (kept copied in: clang before 16 cannot capture a structured binding)
    auto solve = [&, kept = kept](int k) {
      frame.translation.z() = kept == kFramed ? 1e-4 * k : 0.0;
      *scene.positions[slab] = slab_start.rowwise() + frame.translation.transpose();
      solver.Solve(scene.objects);
    };
    solve(0);
    solve(1);
    const long before = allocations.load();
    for (int k = 2; k < 5; ++k) solve(k);
    EXPECT_EQ(allocations.load() - before, 0)
        << DepthMethodName(method) << " " << cell_size << " " << kept;
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
// nothing.
TEST(Allocation, WarmSolvesOfAPileInStripsAllocateNothing) {
  testing::TestScene scene = testing::SphereLayer(24, 13);
  std::vector<Positions> start;
  for (const auto& x : scene.positions) start.push_back(*x);
  PenetrationOptions options;
  options.num_threads = 1;
  PenetrationSolver solver(options);
  auto solve = [&](int k) {  // (sphere o down by k x 0.1, 0.2 or 0.3 mm, by o % 3)
    for (size_t o = 0; o < start.size(); ++o) {
      *scene.positions[o] = start[o];
      scene.positions[o]->col(2).array() -= 1e-4 * k * static_cast<double>(1 + o % 3);
    }
    solver.Solve(scene.objects);
  };
  for (int k = 0; k < 5; ++k) solve(k);
  const long before = allocations.load();
  for (int k = 0; k < 5; ++k) solve(k);
  EXPECT_EQ(allocations.load() - before, 0);
  EXPECT_GT(solver.results().size(), 1000u);
}

}  // namespace
}  // namespace tetcosim
