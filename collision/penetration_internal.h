#pragma once

// What the penetration solver's files share (internal to collision/:
// included by penetration.cc and the stages' files, colliding_points.cc,
// surfaces.cc, border_points.cc, propagation.cc and closest_features.cc).

#include <Eigen/Core>
#include <algorithm>
#include <chrono>
#include <cstddef>
#include <limits>
#include <span>
#include <vector>

#include "mesh/tet_mesh.h"
#include "mesh/vector_room.h"

namespace tetcosim {

using Clock = std::chrono::steady_clock;

inline double SecondsSince(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

// Stage 2 tests every entry of a triangle hash, four boxes at a time, instead
// of looking up a segment's cells when the segment covers more cells than
// the hash has entries over this (a cell's lookup costs about as much as
// testing this many boxes): an edge far longer than the cell, such as one
// of a coarse rigid proxy whose corner is inside a finely meshed body,
// would otherwise visit millions of cells.
constexpr long kEntriesPerCellLookup = 4;

// Stage 1 takes the tetrahedra of an object in chunks of this many, the
// runs that TetMesh::spatial_tet_order keeps compact, and looks up the
// cells of a chunk's union of boxes once, unless they are more than
// kMaxChunkCells. (16: the fewest instructions over the benchmark scenes
// among 4, 8, 16 and 32.) An object's last chunk also takes the remainder
// (up to 2 kChunkTets - 1 tets): a paper sphere's 20 tets are one chunk,
// not a chunk of 16 and one of 4 that looks up the same cells again.
constexpr int kChunkTets = TetMesh::kSpatialRun;
// stage 1 runs on several threads from this many chunks per thread, which
// take this many at a time
constexpr int kMinChunksPerThread = 512 / kChunkTets;
constexpr int kChunksPerGrab = std::max(1, 256 / kChunkTets);

// Grows a bounding box by kBoxMargin times its largest extent on every side.
// The inside and crossing tests accept points a relative 1e-12 outside
// (kBarycentricTolerance, kSegmentTriangleTolerance), so a point on a
// face may lie outside the exact box by a rounding error and still count;
// the broad-phase boxes must not drop it.
constexpr double kBoxMargin = 1e-9;

inline void Inflate(Eigen::Vector3d& lo, Eigen::Vector3d& hi) {
  const Eigen::Vector3d margin = Eigen::Vector3d::Constant(kBoxMargin * (hi - lo).maxCoeff());
  lo -= margin;
  hi += margin;
}

// The bounding box of N points, grown by Inflate: the broad-phase box of a
// tetrahedron, a triangle or a segment.
template <int N>
inline void InflatedBounds(const Eigen::Vector3d (&points)[N], Eigen::Vector3d& lo,
                           Eigen::Vector3d& hi) {
  // (in locals: lo and hi might alias the points, which would force reloads)
  Eigen::Vector3d box_lo = points[0], box_hi = points[0];
  for (int i = 1; i < N; ++i) {
    box_lo = box_lo.cwiseMin(points[i]);
    box_hi = box_hi.cwiseMax(points[i]);
  }
  Inflate(box_lo, box_hi);
  lo = box_lo;
  hi = box_hi;
}

// A few vertices of an object spread over its numbering (SpreadVertex): a
// fixed or framed object's samples, compared every solve
// (CollisionObject::fixed, ::frame), and the check of a given box
// (CheckGivenBounds).
constexpr int kSampledVertices = 16;
// Vertex i of n + 1 spread evenly over a numbering of num_vertices: i = 0 is
// the first, i = n the last.
inline long SpreadVertex(long i, long n, long num_vertices) {
  return (num_vertices - 1) * i / n;
}

// How many of the num_threads threads a loop of n items should use: one per
// min_per_thread items at least. Waking and joining a team costs about as
// much as a few thousand cheap iterations, so short loops run on one.
inline int ThreadsFor(int num_threads, int n, int min_per_thread) {
  return std::clamp(n / min_per_thread, 1, std::max(1, num_threads));
}

// Per-thread buffers of a loop whose items fall to the threads differently
// from solve to solve (dynamic schedules, and the surfaces made alongside
// stage 1): made ready before the loop, so that solving a scene like the
// last allocates nothing, however the items fall. (A thread's buffer
// otherwise grows the first time its share is larger than ever, which may
// be hundreds of solves after the last growth: measured on the crowded
// scene of the determinism tests on two threads.)
//
// ClearForAnyShare: `buffer` collects what a thread's items find (stage 1's
// hits, the candidates of stages 2 and 4): emptied, each keeps room for
// what all threads' held together, and `extra` more (an item that lists up
// to that many and then takes them back: a point's neighbours). A thread's
// buffer holds up to all of a loop's output, as one thread's would: stage
// 1's hits, 64 bytes a colliding point (x86-64-v3), times the threads.
template <typename Scratch, typename T>
void ClearForAnyShare(std::span<Scratch> scratch, std::vector<T> Scratch::*buffer,
                      std::size_t extra = 0) {
  std::size_t all = extra;
  for (const Scratch& thread : scratch) all += (thread.*buffer).size();
  for (Scratch& thread : scratch) {
    (thread.*buffer).clear();
    ReserveWithRoom(thread.*buffer, all);
  }
}
// ReserveLikeLargest: `buffer` holds one item's work at a time (an object's
// faces in play): each gets the capacity of the largest.
template <typename Scratch, typename T>
void ReserveLikeLargest(std::span<Scratch> scratch, std::vector<T> Scratch::*buffer) {
  std::size_t most = 0;
  for (const Scratch& thread : scratch) most = std::max(most, (thread.*buffer).capacity());
  for (Scratch& thread : scratch) (thread.*buffer).reserve(most);
}

// The cells of the box [lo, hi] of cells: 0 if it is empty, and saturated
// at the largest long (a box across the whole clamped grid has 2^93).
inline long CellCount(const Eigen::Vector3i& lo, const Eigen::Vector3i& hi) {
  long count = 1;
  for (int a = 0; a < 3; ++a) {
    const long n = static_cast<long>(hi[a]) - lo[a] + 1;
    if (n <= 0) return 0;
    if (__builtin_mul_overflow(count, n, &count)) return std::numeric_limits<long>::max();
  }
  return count;
}

}  // namespace tetcosim
