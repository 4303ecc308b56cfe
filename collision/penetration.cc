#include "collision/penetration.h"

#include <omp.h>

#if defined(__AVX__)
#include <immintrin.h>
#endif

#include <algorithm>
#include <atomic>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <limits>
#include <numeric>
#include <string>
#include <thread>

#include "collision/geometry.h"
#include "mesh/error.h"
#include "mesh/group_by_key.h"
#include "mesh/parallel_for.h"
#include "mesh/same_bits.h"

namespace tetcosim {
namespace {

using Clock = std::chrono::steady_clock;

double SecondsSince(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

// Triangles whose bounding box covers more cells than this are not hashed but
// tested against every query (large faces of coarse rigid proxies).
constexpr long kMaxTriangleCells = 64;
// Tetrahedra whose bounding box covers more cells than this are searched
// apart (SearchLargeTets), not cell by cell.
constexpr long kMaxTetCells = 512;
// From this many such tetrahedra in a solve, the hashed vertices go into a
// coarser grid first (its cells kCoarseCellFactor times the size), which
// costs about as much as this many tets testing every hashed vertex
// (measured on 100 fine cubes on a slab, BM_MediumSlab: 0.73 ms to grid
// 68k entries, about 20 us for a tet to test them all).
constexpr int kMinCoarseLargeTets = 32;
constexpr double kCoarseCellFactor = 8.0;
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
// stage 1's vertex pass classifies the vertices in blocks of this many
constexpr int kVertexBlock = 1024;
// on several threads, the surfaces of up to this many objects with partners
// per thread are made alongside stage 1 (Solve)
constexpr int kMaxSurfacesAheadPerThread = 4;
constexpr long kMaxChunkCells = 64;
// Stage 4 computes a layer on several threads from this many points per
// thread. A point takes about 40 ns; on two threads the layers of the 70%
// cubes (up to a few hundred points) took longer together than on one,
// with 32 (15.1-15.7 against 12.3 us; 25.7 when the cores were far apart,
// build/bench/two_cores: 450-550 ns round trip), and 12.7-12.9 us with 256.
constexpr int kMinLayerPointsPerThread = 256;
// Objects with more partners than this look up all vertices near a
// tetrahedron at once instead of partner by partner (stage 1).
constexpr int kMaxKeyedPartners = 4;
// Objects with at most this many surface triangles (the paper's 20-tet
// spheres) are not hashed: a query tests their few triangles directly,
// which is cheaper than walking the cells of a segment or a box tree.
constexpr int kSmallSurface = 48;
// Closest features search a larger object through a box tree when it has
// at least this many queries in a solve, else all its triangles (building
// a tree costs about as much as 1.5 searches of every triangle: 15 to 19 ns
// per triangle against 12).
constexpr int kMinTreeQueries = 2;
// Stage 2 finds the triangles too large to hash that a segment meets
// through a box tree when an object has more than this many, else by
// testing each (a coarse floor mesh under fine bodies has thousands).
constexpr int kMaxLargeListed = 16;
// Stage 1's hits are sorted by comparison, not counted vertex by vertex,
// when there are more than this many vertices per hit.
constexpr int kMinVerticesPerCountedHit = 32;

// Whether stage 1 tests the vertices of object a against the tetrahedra of
// object b (a vertex in b's search box may be of any object).
bool MayPenetrate(std::span<const CollisionObject> objects, int a, int b) {
  return a == b ? objects[b].self_collision : !(objects[a].rigid && objects[b].rigid);
}

// Bit i of the outcode: p lies beyond side i of the box (x below, x above,
// y below, ...); 0 inside. A set of points whose outcodes share a bit lies
// beyond one side, and so does their bounding box.
std::uint8_t Outcode(const Eigen::Vector3d& p, const Eigen::Vector3d& lo,
                     const Eigen::Vector3d& hi) {
  return static_cast<std::uint8_t>((p.x() < lo.x()) | (p.x() > hi.x()) << 1 |
                                   (p.y() < lo.y()) << 2 | (p.y() > hi.y()) << 3 |
                                   (p.z() < lo.z()) << 4 | (p.z() > hi.z()) << 5);
}

// (a triangle's three corners are read as one row, by CornersInBox's callers)
static_assert(Triangles::IsRowMajor);

// Whether a triangle (its three corners' vertex numbers) may meet a box,
// told by its corners' outcodes against it: not when all three lie beyond
// one of the box's sides (then so does the triangle's box, even grown
// outward: a box around points is apart from another exactly when the
// points all lie beyond one of its sides).
bool CornersInBox(const std::uint8_t* outcode, const int* corner) {
  return (outcode[corner[0]] & outcode[corner[1]] & outcode[corner[2]]) == 0;
}

// Four doubles in one SIMD register (AVX with x86-64-v3, two SSE2 registers
// with the baseline), through the compiler's vector extension; a comparison
// gives lanes of all ones (true) or zeros.
using Double4 = double __attribute__((vector_size(4 * sizeof(double))));
using Mask4 = std::int64_t __attribute__((vector_size(4 * sizeof(double))));

// Lane i holds i: lanes e + i at or past an end are masked off with it.
constexpr Mask4 kLanes = {0, 1, 2, 3};

Double4 Load4(const double* p) {
  Double4 v;
  std::memcpy(&v, p, sizeof v);
  return v;
}

// Bit i set: lane i of the mask is true (one instruction with AVX: the
// lanes' sign bits; the general expression takes about ten).
unsigned Bits(const Mask4& mask) {
#if defined(__AVX__)
  return static_cast<unsigned>(_mm256_movemask_pd(reinterpret_cast<__m256d>(mask)));
#else
  return static_cast<unsigned>((mask[0] & 1) | (mask[1] & 2) | (mask[2] & 4) | (mask[3] & 8));
#endif
}

// An axis-aligned box that tests four points at a time (stage 1: about 20
// candidate vertices per tetrahedron, one of them in its box).
class Box4 {
 public:
  Box4(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi)
      : lo_x_(Double4{} + lo.x()),
        lo_y_(Double4{} + lo.y()),
        lo_z_(Double4{} + lo.z()),
        hi_x_(Double4{} + hi.x()),
        hi_y_(Double4{} + hi.y()),
        hi_z_(Double4{} + hi.z()) {}

  // Bit j set: box i + j (< end) of the boxes [lo[k][i], hi[k][i]] (k:
  // the axis) overlaps this one (reads four boxes from i).
  unsigned Overlapping(const std::vector<double> (&lo)[3], const std::vector<double> (&hi)[3],
                       int i, int end) const {
    return Bits((Load4(&lo[0][i]) <= hi_x_) & (lo_x_ <= Load4(&hi[0][i])) &
                (Load4(&lo[1][i]) <= hi_y_) & (lo_y_ <= Load4(&hi[1][i])) &
                (Load4(&lo[2][i]) <= hi_z_) & (lo_z_ <= Load4(&hi[2][i])) & (kLanes + i < end));
  }

  // Bit j set: box j of four boxes [lo[k][j], hi[k][j]] overlaps this one.
  unsigned Overlapping(const double (&lo)[3][4], const double (&hi)[3][4]) const {
    return Bits((Load4(lo[0]) <= hi_x_) & (lo_x_ <= Load4(hi[0])) & (Load4(lo[1]) <= hi_y_) &
                (lo_y_ <= Load4(hi[1])) & (Load4(lo[2]) <= hi_z_) & (lo_z_ <= Load4(hi[2])));
  }

  // visit(e), in increasing order, for every entry e in [begin, end) of
  // points whose position lies in the box (lo <= p <= hi in every
  // coordinate; NaN is outside), four entries at a time (reading up to
  // three entries beyond end: the arrays' padding)
  template <typename Points, typename Visit>
  void ForEachInside(const Points& points, int begin, int end, Visit&& visit) const {
    for (int e = begin; e < end; e += 4) {
      const Double4 x = Load4(&points.x[e]), y = Load4(&points.y[e]), z = Load4(&points.z[e]);
      const Mask4 inside = (x >= lo_x_) & (x <= hi_x_) & (y >= lo_y_) & (y <= hi_y_) &
                           (z >= lo_z_) & (z <= hi_z_) & (kLanes + e < end);
      for (unsigned bits = Bits(inside); bits != 0; bits &= bits - 1) {
        visit(e + std::countr_zero(bits));
      }
    }
  }

 private:
  Double4 lo_x_, lo_y_, lo_z_, hi_x_, hi_y_, hi_z_;
};

// Lane j of four vectors by coordinate (values[k][j]: coordinate k of
// vector j), as a vector.
Eigen::Vector3d Lane(const double (&values)[3][4], int j) {
  return {values[0][j], values[1][j], values[2][j]};
}

// SegmentTriangle (geometry.h) for four triangles by coordinate (lane j of
// corner[k], edge0[k], edge1[k] and edge_lengths: TriangleGeometry's
// corner[0], edge[0], edge[1] and edge_lengths of triangle j), the same
// arithmetic lane by lane. Bit j set: the segment from q to q + dir crosses
// triangle j, at t[j], (u[j], v[j]).
unsigned SegmentTriangles4(const Eigen::Vector3d& q, const Eigen::Vector3d& dir, double dir_length,
                           const double (&corner)[3][4], const double (&edge0)[3][4],
                           const double (&edge1)[3][4], const double (&edge_lengths)[4], Double4& t,
                           Double4& u, Double4& v) {
  constexpr double kTolerance = kSegmentTriangleTolerance;
  const Double4 e1[3] = {Load4(edge0[0]), Load4(edge0[1]), Load4(edge0[2])};
  const Double4 e2[3] = {Load4(edge1[0]), Load4(edge1[1]), Load4(edge1[2])};
  const Double4 h[3] = {dir.y() * e2[2] - dir.z() * e2[1], dir.z() * e2[0] - dir.x() * e2[2],
                        dir.x() * e2[1] - dir.y() * e2[0]};
  const Double4 det = e1[0] * h[0] + e1[1] * h[1] + e1[2] * h[2];
  const Double4 scale = Load4(edge_lengths) * dir_length;
  const Double4 inv = 1.0 / det;
  const Double4 s[3] = {q.x() - Load4(corner[0]), q.y() - Load4(corner[1]),
                        q.z() - Load4(corner[2])};
  u = (s[0] * h[0] + s[1] * h[1] + s[2] * h[2]) * inv;
  const Double4 k[3] = {s[1] * e1[2] - s[2] * e1[1], s[2] * e1[0] - s[0] * e1[2],
                        s[0] * e1[1] - s[1] * e1[0]};
  v = (dir.x() * k[0] + dir.y() * k[1] + dir.z() * k[2]) * inv;
  t = (e2[0] * k[0] + e2[1] * k[1] + e2[2] * k[2]) * inv;
  const Double4 min_det = kSegmentTriangleParallel * scale;
  return Bits(((det > min_det) | (-det > min_det)) & (scale != 0.0) & (u >= -kTolerance) &
              (u <= 1.0 + kTolerance) & (v >= -kTolerance) & (u + v <= 1.0 + kTolerance) &
              (t >= -kTolerance) & (t <= 1.0 + kTolerance));
}

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
void InflatedBounds(const Eigen::Vector3d (&points)[N], Eigen::Vector3d& lo, Eigen::Vector3d& hi) {
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

// How many of the num_threads threads a loop of n items should use: one per
// min_per_thread items at least. Waking and joining a team costs about as
// much as a few thousand cheap iterations, so short loops run on one.
int ThreadsFor(int num_threads, int n, int min_per_thread) {
  return std::clamp(n / min_per_thread, 1, std::max(1, num_threads));
}

// The cells of the box [lo, hi] of cells: 0 if it is empty, and saturated
// at the largest long (a box across the whole clamped grid has 2^93).
long CellCount(const Eigen::Vector3i& lo, const Eigen::Vector3i& hi) {
  long count = 1;
  for (int a = 0; a < 3; ++a) {
    const long n = static_cast<long>(hi[a]) - lo[a] + 1;
    if (n <= 0) return 0;
    if (__builtin_mul_overflow(count, n, &count)) return std::numeric_limits<long>::max();
  }
  return count;
}

}  // namespace

// (Row by row, in one pass: Eigen's column-wise reduction of a row-major
// matrix walks each column on its own, six passes. Grown in a local and
// copied out: grown in the returned object, which the positions might
// alias as far as the compiler knows, it was kept in memory, 0.5% more
// instructions a solve on the scenes.)
PositionBounds PositionBounds::Of(const Positions& x) {
  PositionBounds grown;
  for (int v = 0; v < x.rows(); ++v) grown.Add(x.row(v).transpose());
  PositionBounds bounds = grown;
  return bounds;
}

static_assert(std::endian::native == std::endian::little);  // (bytes of a word, below)

// Bit 8 i + 7 set just when byte i (in memory order) of the word is zero.
std::uint64_t ZeroByteMask(std::uint64_t word) {
  constexpr std::uint64_t kLow7 = 0x7F7F7F7F7F7F7F7F;
  // (a byte's low seven bits plus 0x7F carry into its high bit unless all
  // zero; or-ed with the byte's own high bit: set unless the byte is zero)
  return ~(((word & kLow7) + kLow7) | word | kLow7);
}

// The number of zero bytes in [begin, end), eight at a time.
int CountZeroBytes(const std::uint8_t* bytes, int begin, int end) {
  int count = 0;
  int i = begin;
  for (; i + 8 <= end; i += 8) {
    std::uint64_t word;
    std::memcpy(&word, bytes + i, sizeof(word));
    count += std::popcount(ZeroByteMask(word));
  }
  for (; i < end; ++i) count += bytes[i] == 0;
  return count;
}

// visit(i) for every i in [begin, end) with bytes[i] == 0, in increasing
// order, passing over eight non-zero bytes at a time (the outcodes of
// vertices outside every search box, most of a large body's)
template <typename Visit>
void ForEachZeroByte(const std::uint8_t* bytes, int begin, int end, Visit&& visit) {
  int i = begin;
  for (; i + 8 <= end; i += 8) {
    std::uint64_t word;
    std::memcpy(&word, bytes + i, sizeof(word));
    for (std::uint64_t zero = ZeroByteMask(word); zero != 0; zero &= zero - 1) {
      visit(i + std::countr_zero(zero) / 8);
    }
  }
  for (; i < end; ++i) {
    if (bytes[i] == 0) visit(i);
  }
}

// A kept object's vertices beyond every side of its search box: those of
// the chunks that stage 1 passes over (geometrically impossible, and so
// never taken for a real outcode)
constexpr std::uint8_t kBeyondEverySide = 0x3F;
// a fixed or framed object's vertices compared every solve
// (CollisionObject::fixed, ::frame)
constexpr int kKeptSamples = 16;
// A framed object's positions taken into its body frame differ from one
// solve to the next by rounding, a few ulp of the coordinates' magnitude
// (body-frame and translation): a sample may differ by kFrameRounding
// times that magnitude, the kept boxes are grown by kFramePad times it
// (at keeping), and they are kept anew when the magnitude has grown so far
// (a body carried far away) that the rounding could reach an eighth of the
// growth.
constexpr double kFrameRounding = 1e-12;
constexpr double kFramePad = 1e-9;
// how far R^T R may be from the identity, entry by entry, for a rotation
constexpr double kRotationTolerance = 1e-9;

const char* DepthMethodName(DepthMethod method) {
  return method == DepthMethod::kConsistent ? "consistent" : "closest";
}

const char* DepthSourceName(DepthSource source) {
  switch (source) {
    case DepthSource::kBorder:
      return "border";
    case DepthSource::kPropagated:
      return "propagated";
    case DepthSource::kFallback:
      return "fallback";
    case DepthSource::kClosest:
      return "closest";
  }
  return "?";
}

PenetrationSolver::PenetrationSolver(PenetrationOptions options) {
  set_options(options);
}

void PenetrationSolver::set_options(const PenetrationOptions& options) {
  if (!(options.cell_size >= 0.0) || !std::isfinite(options.cell_size)) {
    char value[32];
    std::snprintf(value, sizeof(value), "%g", options.cell_size);
    throw Error(std::string("penetration solver: the cell size is ") + value +
                " m; give a finite length >= 0 (0: the average edge length)");
  }
  options_ = options;
}

void PenetrationSolver::ResizePadded(std::vector<double>& values, int n) {
  values.resize(n + kSimdPadding);
  std::fill(values.begin() + n, values.end(), std::numeric_limits<double>::quiet_NaN());
}

Eigen::Vector3d PenetrationSolver::Position(int global_vertex) const {
  int object = vertex_object_[global_vertex];
  return positions_[object]->row(global_vertex - vertex_offset_[object]).transpose();
}

int PenetrationSolver::FindHit(int vertex, int penetrated) const {
  const auto [begin, end] = hit_range_[vertex];
  for (int h = begin; h < end; ++h) {
    if (hits_[h].penetrated == penetrated) return h;
  }
  return -1;
}

const std::vector<PenetrationResult>& PenetrationSolver::Solve(
    std::span<const CollisionObject> objects) {
  Clock::time_point start = Clock::now();
  timings_ = {};
  stats_ = {};
  Prepare(objects);
  timings_.hash = SecondsSince(start);
  // stage 1 and the surfaces at once, on several threads, for scenes of a
  // few objects with partners: the surfaces are then made before it is
  // known which objects are penetrated, and in a pile of small bodies many
  // boxes overlap without penetration (120 spheres on two threads: 13%
  // slower, from surfaces made in vain). Not for closest features either,
  // which hash whole surfaces.
  const int threads = ThreadsFor(options_.num_threads, chunk_offset_.back(), kMinChunksPerThread);
  if (threads > 1 && static_cast<int>(partnered_.size()) <= kMaxSurfacesAheadPerThread * threads &&
      options_.method == DepthMethod::kConsistent) {
    FindCollidingPointsAndHashSurfaces(objects, threads);
  } else {
    FindCollidingPoints(objects);
    HashSurfaces(objects, /*full=*/options_.method == DepthMethod::kClosest);
  }
  if (options_.method == DepthMethod::kConsistent) {
    ComputeBorderPoints(objects);
    Propagate(objects);
    if (options_.fallback) ComputeClosest(objects, /*all=*/false);
  } else {
    ComputeClosest(objects, /*all=*/true);
  }
  CollectResults(objects);
  timings_.total = SecondsSince(start);
  return results_;
}

// global numbering of vertices, current normals, cell size
void PenetrationSolver::Prepare(std::span<const CollisionObject> objects) {
  const int num_objects = static_cast<int>(objects.size());
  vertex_offset_.resize(num_objects + 1);
  vertex_offset_[0] = 0;
  positions_.resize(num_objects);
  normals_.resize(num_objects);
  double edge_sum = 0.0;
  long edge_count = 0;
  for (int o = 0; o < num_objects; ++o) {
    const CollisionObject& object = objects[o];
    if (object.mesh == nullptr || object.positions == nullptr ||
        object.positions->rows() != object.mesh->num_vertices()) [[unlikely]] {
      throw Error("penetration solver: object " + std::to_string(o) +
                  (object.mesh == nullptr || object.positions == nullptr
                       ? " has no mesh or no positions"
                       : " has " + std::to_string(object.positions->rows()) +
                             " positions for a mesh of " +
                             std::to_string(object.mesh->num_vertices()) + " vertices") +
                  "; give every object its mesh and one position per vertex");
    }
    vertex_offset_[o + 1] = vertex_offset_[o] + object.mesh->num_vertices();
    positions_[o] = object.positions;
    edge_sum +=
        object.mesh->average_edge_length() * static_cast<double>(object.mesh->edges().rows());
    edge_count += object.mesh->edges().rows();
  }
  const int num_vertices = vertex_offset_[num_objects];
  // stage 1's chunks of tets, object after object: the runs of each
  // object's spatial order (TetMesh::num_spatial_runs)
  chunk_offset_.resize(num_objects + 1);
  chunk_offset_[0] = 0;
  for (int o = 0; o < num_objects; ++o) {
    chunk_offset_[o + 1] = chunk_offset_[o] + objects[o].mesh->num_spatial_runs();
  }
  if (vertex_offset_ != object_of_offset_) {  // (the same objects: already filled)
    vertex_object_.resize(num_vertices);
    for (int o = 0; o < num_objects; ++o) {
      std::fill(vertex_object_.begin() + vertex_offset_[o],
                vertex_object_.begin() + vertex_offset_[o + 1], o);
    }
    object_of_offset_ = vertex_offset_;
  }
  length_scale_ = edge_count > 0 ? edge_sum / static_cast<double>(edge_count) : 1.0;
  cell_size_ = options_.cell_size > 0.0 ? options_.cell_size : length_scale_;
  inverse_cell_size_ = 1.0 / cell_size_;  // (as SpatialHash::Reset computes it)
  // broad phase: bounding boxes; per object B its partners (the objects
  // whose boxes overlap B's and that may collide with it, B itself with
  // self-collision), found by sweep and prune (below), and the region where
  // they can reach into B: the union of the boxes' overlaps.
  object_lo_.resize(num_objects);
  object_hi_.resize(num_objects);
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();  // (of the boxes' centres, left out aside)
  int num_in = 0;
  kept_.resize(num_objects);
  any_kept_ = false;
  for (int o = 0; o < num_objects; ++o) {
    KeptObject& kept = kept_[o];
    const bool keepable = objects[o].fixed || objects[o].frame != nullptr;
    kept.active = keepable && KeepObject(objects[o], kept);
    if (!keepable) kept.mesh = nullptr;          // (seen moving: keep nothing)
    if (!kept.active) kept.outcode_offset = -1;  // (its outcodes: all written)
    any_kept_ |= kept.active;
    stats_.fixed_objects += kept.active && !kept.framed;
    stats_.framed_objects += kept.active && kept.framed;
    Eigen::Vector3d lo, hi;
    bool finite;
    if (kept.active && !kept.framed) {
      lo = kept.lo;
      hi = kept.hi;
      finite = kept.finite;
    } else {
      // the caller's pass over the positions, if it gives its box, else ours
      const RigidFrame* frame = objects[o].frame;
      const bool given = frame != nullptr && frame->bounds.has_value();
      if (given) CheckGivenBounds(objects[o], o);
      const PositionBounds bounds =
          given ? *frame->bounds : PositionBounds::Of(*objects[o].positions);
      lo = bounds.lo;
      hi = bounds.hi;
      finite = bounds.finite();
    }
    if (!finite) {
      // left out: an empty box meets no other, and sorts last
      ++stats_.non_finite_objects;
      lo.setConstant(std::numeric_limits<double>::infinity());
      hi = -lo;
    } else {
      Inflate(lo, hi);
      mean += 0.5 * (lo + hi);
      ++num_in;
    }
    object_lo_[o] = lo;
    object_hi_[o] = hi;
  }
  mean /= std::max(1, num_in);
  // the sweep axis: the one along which the boxes' centres spread most
  // (their variance), so that the fewest boxes start before a box ends
  // along it (a pile of 9600 spheres, 20 x 80 x 6, swept along x: 360
  // boxes tested a box, 13 overlapping it, and the broad phase was 18% of
  // the solve's instructions; along y, 10%)
  Eigen::Vector3d spread = Eigen::Vector3d::Zero();
  for (int o = 0; o < num_objects; ++o) {
    if (object_lo_[o].x() > object_hi_[o].x()) continue;  // (left out)
    spread += (0.5 * (object_lo_[o] + object_hi_[o]) - mean).cwiseAbs2();
  }
  int axis = 0;
  spread.maxCoeff(&axis);  // (the first of equal ones)
  pairs_.clear();
  sweep_order_.resize(num_objects);
  for (int o = 0; o < num_objects; ++o) sweep_order_[o] = o;
  std::sort(sweep_order_.begin(), sweep_order_.end(), [&](int a, int b) {
    const double a_lo = object_lo_[a][axis], b_lo = object_lo_[b][axis];
    return a_lo != b_lo ? a_lo < b_lo : a < b;
  });
  // the boxes in sweep order by coordinate: a box is tested against the
  // boxes after it that start before it ends along the axis, four at a
  // time (in a pile of 120 spheres, about 50 of them per box)
  for (int k = 0; k < 3; ++k) {
    ResizePadded(sweep_lo_[k], num_objects);
    ResizePadded(sweep_hi_[k], num_objects);
    for (int i = 0; i < num_objects; ++i) {
      sweep_lo_[k][i] = object_lo_[sweep_order_[i]][k];
      sweep_hi_[k][i] = object_hi_[sweep_order_[i]][k];
    }
  }
  const std::vector<double>& sweep_lo = sweep_lo_[axis];
  for (int i = 0; i < num_objects; ++i) {
    const int a = sweep_order_[i];
    if (object_lo_[a].x() > object_hi_[a].x()) continue;  // (left out: sorted last)
    if (objects[a].self_collision) pairs_.push_back({a, a});
    // (the boxes that start before this one ends, by bisection)
    const int end =
        static_cast<int>(std::upper_bound(sweep_lo.begin() + i + 1, sweep_lo.begin() + num_objects,
                                          object_hi_[a][axis]) -
                         sweep_lo.begin());
    const Box4 box(object_lo_[a], object_hi_[a]);
    for (int j = i + 1; j < end; j += 4) {
      for (unsigned bits = box.Overlapping(sweep_lo_, sweep_hi_, j, end); bits != 0;
           bits &= bits - 1) {
        const int b = sweep_order_[j + std::countr_zero(bits)];
        if (objects[a].rigid && objects[b].rigid) continue;  // the rigid engine's pair
        pairs_.push_back({a, b});
        pairs_.push_back({b, a});
      }
    }
  }
  // per object its partners, with the overlap of the two boxes, in the
  // order found (deterministic)
  GroupByKey(
      num_objects,
      [&](auto emit) {
        for (int i = 0; i < static_cast<int>(pairs_.size()); ++i) emit(pairs_[i][0], i);
      },
      partner_offset_, partner_pair_);
  partnered_.clear();
  for (int o = 0; o < num_objects; ++o) {
    if (partner_offset_[o + 1] > partner_offset_[o]) partnered_.push_back(o);
  }
  partners_.resize(pairs_.size());
  const double inf = std::numeric_limits<double>::infinity();
  search_lo_.assign(num_objects, Eigen::Vector3d::Constant(inf));
  search_hi_.assign(num_objects, Eigen::Vector3d::Constant(-inf));
  for (size_t k = 0; k < partners_.size(); ++k) {
    const auto [b, a] = pairs_[partner_pair_[k]];
    Partner& partner = partners_[k];
    partner.object = a;
    partner.lo = object_lo_[a].cwiseMax(object_lo_[b]);
    partner.hi = object_hi_[a].cwiseMin(object_hi_[b]);
    search_lo_[b] = search_lo_[b].cwiseMin(partner.lo);
    search_hi_[b] = search_hi_[b].cwiseMax(partner.hi);
  }
  if (!any_kept_) return;
  // a kept object's chunks that stage 1 searches: those whose box meets
  // its search box, found in its tree. (A fixed object's: exactly those
  // that have a vertex in the search box, as a chunk's vertices all lie
  // beyond one side of the search box just when the chunk's box does not
  // meet it; a framed object's: a few more, its search box taken into the
  // body frame and grown.)
  search_chunks_.clear();
  for (int o = 0; o < num_objects; ++o) {
    KeptObject& kept = kept_[o];
    if (!kept.active) {
      for (int c = chunk_offset_[o]; c < chunk_offset_[o + 1]; ++c) search_chunks_.push_back(c);
      continue;
    }
    kept.searched.clear();
    Eigen::Vector3d lo = search_lo_[o], hi = search_hi_[o];
    if (kept.framed && (lo.array() <= hi.array()).all()) {
      // the search box in the body frame: the box around it there, grown
      // as the kept boxes are
      const Eigen::Vector3d centre = kept.ToBody(0.5 * (lo + hi));
      const Eigen::Vector3d half = kept.rotation.transpose().cwiseAbs() * (0.5 * (hi - lo)) +
                                   Eigen::Vector3d::Constant(kept.pad);
      lo = centre - half;
      hi = centre + half;
    }
    kept.runs.Overlapping(lo, hi, [&](int run) { kept.searched.push_back(run); });
    std::sort(kept.searched.begin(), kept.searched.end());
    for (int run : kept.searched) search_chunks_.push_back(chunk_offset_[o] + run);
  }
}

void PenetrationSolver::CheckGivenBounds(const CollisionObject& object, int o) {
  // kKeptSamples vertices spread over the numbering, the first and last
  // among them (a box kept from another placement, or of other positions,
  // leaves out some of them)
  const PositionBounds& bounds = *object.frame->bounds;
  const Positions& x = *object.positions;
  const long num_vertices = x.rows();
  for (long i = 0; i <= kKeptSamples && num_vertices > 0; ++i) {
    const long v = (num_vertices - 1) * i / kKeptSamples;
    const Eigen::Vector3d p = x.row(v).transpose();
    const bool finite = p.allFinite();
    const bool inside =
        (bounds.lo.array() <= p.array()).all() && (p.array() <= bounds.hi.array()).all();
    if (finite ? inside : !bounds.finite()) continue;
    char at[96];
    std::snprintf(at, sizeof(at), " (at %g, %g, %g)", p.x(), p.y(), p.z());
    throw Error("penetration solver: object " + std::to_string(o) +
                ": its frame's bounds do not hold its vertex " + std::to_string(v) + at +
                "; give RigidFrame::bounds as PositionBounds::Add of every position as given, "
                "or leave it unset");
  }
}

bool PenetrationSolver::KeepObject(const CollisionObject& object, KeptObject& kept) {
  const TetMesh& mesh = *object.mesh;
  const Positions& x = *object.positions;
  const int num_vertices = mesh.num_vertices();
  const bool framed = !object.fixed;  // (else it has a frame)
  if (framed) {
    const RigidFrame& frame = *object.frame;
    const double off_identity =
        (frame.rotation.transpose() * frame.rotation - Eigen::Matrix3d::Identity())
            .cwiseAbs()
            .maxCoeff();
    if (!(off_identity <= kRotationTolerance) || !frame.translation.allFinite()) {
      kept.mesh = nullptr;  // (not a rotation: keep nothing)
      return false;
    }
    kept.rotation = frame.rotation;
    kept.translation = frame.translation;
  }
  const bool seen =
      kept.mesh == object.mesh && kept.positions == object.positions && kept.framed == framed;
  kept.framed = framed;
  // a vertex's position, in the body frame if framed
  auto position = [&](int v) { return kept.ToBody(x.row(v).transpose()); };
  if (seen) {
    // (the rounding of the samples as kept, and as now)
    const double magnitude =
        std::max(kept.pad / kFramePad, kept.body_scale + kept.translation.cwiseAbs().maxCoeff());
    const double tolerance = framed ? kFrameRounding * magnitude : 0.0;
    bool still = true;
    for (size_t i = 0; i < kept.sample_vertex.size(); ++i) {
      const Eigen::Vector3d p = position(kept.sample_vertex[i]);
      still &= framed ? (p - kept.sample[i]).cwiseAbs().maxCoeff() <= tolerance
                      : SameBits({p.data(), 3}, {kept.sample[i].data(), 3});
    }
    if (still && kept.built && 8.0 * tolerance <= kept.pad) return true;
    for (size_t i = 0; i < kept.sample_vertex.size(); ++i) {
      kept.sample[i] = position(kept.sample_vertex[i]);
    }
    if (!still) {
      kept.built = false;
      return false;
    }
  } else {
    kept.mesh = object.mesh;
    kept.positions = object.positions;
    const int num_samples = std::min(kKeptSamples, num_vertices);
    kept.sample_vertex.resize(num_samples);
    kept.sample.resize(num_samples);
    for (int i = 0; i < num_samples; ++i) {
      // spread over the numbering, the last vertex among them
      kept.sample_vertex[i] =
          static_cast<int>(static_cast<long>(num_vertices - 1) * (i + 1) / num_samples);
      kept.sample[i] = position(kept.sample_vertex[i]);
    }
  }
  // keep it
  kept.built = true;
  kept.outcode_offset = -1;  // (another object's, or the outcodes written meanwhile)
  const PositionBounds bounds = PositionBounds::Of(x);
  kept.lo = bounds.lo;
  kept.hi = bounds.hi;
  kept.finite = bounds.finite();
  kept.pad = 0.0;
  if (framed) {
    if (!kept.finite) {  // (left out this solve; not kept, as its positions may change)
      kept.mesh = nullptr;
      return false;
    }
    kept.body_scale = 0.0;
    for (int v = 0; v < num_vertices; ++v) {
      kept.body_scale = std::max(kept.body_scale, position(v).cwiseAbs().maxCoeff());
    }
    kept.pad = kFramePad * (kept.body_scale + kept.translation.cwiseAbs().maxCoeff());
  }
  const Eigen::Vector3d pad = Eigen::Vector3d::Constant(kept.pad);
  const int num_runs = mesh.num_spatial_runs();
  const std::vector<int>& run_vertices = mesh.spatial_run_vertices();
  const std::vector<int>& run_offsets = mesh.spatial_run_vertex_offsets();
  kept.run_lo.resize(num_runs);
  kept.run_hi.resize(num_runs);
  std::vector<char> in_run(num_vertices, 0);
  for (int r = 0; r < num_runs; ++r) {
    Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
    Eigen::Vector3d hi = -lo;
    for (int i = run_offsets[r]; i < run_offsets[r + 1]; ++i) {
      lo = lo.cwiseMin(position(run_vertices[i]));
      hi = hi.cwiseMax(position(run_vertices[i]));
      in_run[run_vertices[i]] = 1;
    }
    kept.run_lo[r] = lo - pad;
    kept.run_hi[r] = hi + pad;
  }
  // (a non-finite object is left out of the solve: its trees are empty,
  // no chunk to search, no face to find)
  auto if_finite = [&](const std::vector<Eigen::Vector3d>& boxes) {
    return kept.finite ? std::span<const Eigen::Vector3d>(boxes)
                       : std::span<const Eigen::Vector3d>();
  };
  kept.runs.Build(if_finite(kept.run_lo), if_finite(kept.run_hi));
  kept.loose_vertices.clear();
  for (int v = 0; v < num_vertices; ++v) {
    if (!in_run[v]) kept.loose_vertices.push_back(v);
  }
  // each surface face in the chunk of its tet (the last chunk also takes
  // the remainder of the spatial order)
  std::vector<int> tet_run(mesh.num_tets());
  for (int n = 0; n < mesh.num_tets(); ++n) {
    tet_run[mesh.spatial_tet_order()[n]] = std::min(n / kChunkTets, num_runs - 1);
  }
  const int num_faces = static_cast<int>(mesh.surface().rows());
  kept.run_face_offset.assign(num_runs + 1, 0);
  for (int f = 0; f < num_faces; ++f) ++kept.run_face_offset[tet_run[mesh.surface_tet()[f]] + 1];
  for (int r = 0; r < num_runs; ++r) kept.run_face_offset[r + 1] += kept.run_face_offset[r];
  kept.run_faces.resize(num_faces);
  std::vector<int> next(kept.run_face_offset.begin(), kept.run_face_offset.end() - 1);
  for (int f = 0; f < num_faces; ++f) kept.run_faces[next[tet_run[mesh.surface_tet()[f]]]++] = f;
  kept.face_lo.resize(num_faces);
  kept.face_hi.resize(num_faces);
  for (int f = 0; f < num_faces && kept.finite; ++f) {
    Eigen::Vector3d corner[3];
    for (int k = 0; k < 3; ++k) corner[k] = position(mesh.surface()(f, k));
    InflatedBounds(corner, kept.face_lo[f], kept.face_hi[f]);
    kept.face_lo[f] -= pad;
    kept.face_hi[f] += pad;
  }
  kept.faces.Build(if_finite(kept.face_lo), if_finite(kept.face_hi));
  return true;
}

// stage 1: every vertex inside a tetrahedron of another object
void PenetrationSolver::FindCollidingPoints(std::span<const CollisionObject> objects) {
  Clock::time_point start = Clock::now();
  const int num_vertices = vertex_offset_[objects.size()];
  const int num_threads = std::max(1, options_.num_threads);
  // pass 1: hash the vertices that lie where a partner object can reach
  BeginVertexHash();
  const int num_blocks = (num_vertices + kVertexBlock - 1) / kVertexBlock;
  ParallelFor(ThreadsFor(num_threads, num_blocks, 4), 0, num_blocks, [&](int block) {
    ClassifyVertices(block * kVertexBlock, std::min(num_vertices, (block + 1) * kVertexBlock));
  });
  ClassifyKeptVertices();
  BuildVertexHash(num_threads);
  timings_.hash += SecondsSince(start);

  start = Clock::now();
  const int num_chunks = BeginSearch(objects, num_threads);
  const int num_searched = hash_.num_items() > 0 ? num_chunks : 0;
  ParallelFor(
      ThreadsFor(num_threads, num_searched, kMinChunksPerThread), 0, num_searched,
      [&](int i) { SearchChunk(objects, SearchedChunk(i)); }, Schedule::kDynamic, kChunksPerGrab);
  SearchLargeTets(objects);
  MergeHits();
  timings_.inside += SecondsSince(start);
}

// stage 1 and the surfaces on several threads, in one parallel region: the
// vertex hash is built by one thread while the others make the surfaces of
// the objects that have partners (those that can be penetrated: made before
// it is known which are, so some may be made in vain); every thread then
// joins stage 1 as soon as the hash is built and the surfaces are taken.
// On two cubes of 1250 tets on two threads, the serial hash was a tenth of
// the solve.
void PenetrationSolver::FindCollidingPointsAndHashSurfaces(std::span<const CollisionObject> objects,
                                                           int threads) {
  const Clock::time_point start = Clock::now();
  const int num_objects = static_cast<int>(objects.size());
  const int num_vertices = vertex_offset_[num_objects];
  surface_list_.assign(partnered_.begin(), partnered_.end());
  const int num_surfaces = static_cast<int>(surface_list_.size());
  BeginVertexHash();
  ClassifyKeptVertices();  // (before the surfaces, which read the outcodes)
  PlaceSurfaces(objects, /*full=*/false);
  const int num_chunks = BeginSearch(objects, threads);
  std::atomic<bool> hash_built = false;
  std::atomic<int> surfaces_left = num_surfaces;
  Clock::time_point hash_end = start, surfaces_end = start;
#pragma omp parallel num_threads(threads)
  {
#pragma omp for schedule(static)
    for (int part = 0; part < threads; ++part) {  // (an even share each)
      ClassifyVertices(static_cast<int>(static_cast<long>(num_vertices) * part / threads),
                       static_cast<int>(static_cast<long>(num_vertices) * (part + 1) / threads));
    }
#pragma omp single nowait
    {
      BuildVertexHash(/*num_threads=*/1);  // (the other threads make surfaces meanwhile)
      hash_end = Clock::now();
      hash_built.store(true, std::memory_order_release);
    }
#pragma omp for schedule(dynamic, 1) nowait
    for (int i = 0; i < num_surfaces; ++i) {
      HashSurface(objects, surface_list_[i]);
      if (surfaces_left.fetch_sub(1, std::memory_order_acq_rel) == 1) surfaces_end = Clock::now();
    }
    while (!hash_built.load(std::memory_order_acquire)) std::this_thread::yield();
    const int num_searched = hash_.num_items() > 0 ? num_chunks : 0;
#pragma omp for schedule(dynamic, kChunksPerGrab) nowait
    for (int i = 0; i < num_searched; ++i) SearchChunk(objects, SearchedChunk(i));
  }
  SearchLargeTets(objects);
  MergeHits();
  // the stages overlap: the wall time is split where the hash was built
  // and where the last surface was made
  const Clock::time_point surfaces_from = std::max(hash_end, surfaces_end);
  timings_.hash += std::chrono::duration<double>(hash_end - start).count();
  timings_.surfaces += std::chrono::duration<double>(surfaces_from - hash_end).count();
  timings_.inside += SecondsSince(surfaces_from);
}

void PenetrationSolver::BeginVertexHash() {
  const int num_vertices = vertex_offset_.back();
  vertex_cell_.resize(num_vertices);
  vertex_outcode_.resize(num_vertices);
}

void PenetrationSolver::ClassifyVertices(int begin, int end) {
  for (int g = begin; g < end;) {  // object by object
    const int o = vertex_object_[g];
    const int offset = vertex_offset_[o];
    const int stop = std::min(end, vertex_offset_[o + 1]);
    if (kept_[o].active) {  // (ClassifyKeptVertices)
      g = stop;
      continue;
    }
    const Positions& x = *positions_[o];
    const Eigen::Vector3d lo = search_lo_[o], hi = search_hi_[o];
    std::uint8_t* outcode = vertex_outcode_.data() + offset;
    Eigen::Vector3i* cell = vertex_cell_.data() + offset;
    for (int v = g - offset; v < stop - offset; ++v) {
      const Eigen::Vector3d p = x.row(v).transpose();
      outcode[v] = Outcode(p, lo, hi);
      if (outcode[v] == 0) cell[v] = Cell(p);
    }
    g = stop;
  }
}

void PenetrationSolver::ClassifyKeptVertices() {
  if (!any_kept_) return;
  const int num_objects = static_cast<int>(kept_.size());
  for (int o = 0; o < num_objects; ++o) {
    KeptObject& kept = kept_[o];
    if (!kept.active) continue;
    const int offset = vertex_offset_[o];
    std::uint8_t* outcode = vertex_outcode_.data() + offset;
    Eigen::Vector3i* cell = vertex_cell_.data() + offset;
    // (all set once while the object stays kept and in its place among the
    // objects; then only those classified in the last solve are reset)
    if (kept.outcode_offset != offset) {
      std::fill(outcode, outcode + (vertex_offset_[o + 1] - offset), kBeyondEverySide);
      kept.outcode_offset = offset;
    } else {
      for (int v : kept.classified) outcode[v] = kBeyondEverySide;
    }
    kept.classified.clear();
    kept.hashed.clear();
    const Positions& x = *positions_[o];
    const Eigen::Vector3d lo = search_lo_[o], hi = search_hi_[o];
    auto classify = [&](int v) {
      const Eigen::Vector3d p = x.row(v).transpose();
      outcode[v] = Outcode(p, lo, hi);
      kept.classified.push_back(v);
      if (outcode[v] == 0) {
        cell[v] = Cell(p);
        kept.hashed.push_back(v);
      }
    };
    // (a vertex shared by several chunks is classified again, alike)
    const std::vector<int>& run_vertices = kept.mesh->spatial_run_vertices();
    const std::vector<int>& run_offsets = kept.mesh->spatial_run_vertex_offsets();
    for (int run : kept.searched) {
      for (int i = run_offsets[run]; i < run_offsets[run + 1]; ++i) classify(run_vertices[i]);
    }
    for (int v : kept.loose_vertices) classify(v);
    // (in vertex order, as the other objects' vertices are hashed)
    std::sort(kept.hashed.begin(), kept.hashed.end());
    kept.hashed.erase(std::unique(kept.hashed.begin(), kept.hashed.end()), kept.hashed.end());
  }
}

void PenetrationSolver::BuildVertexHash(int num_threads) {
  const int num_objects = static_cast<int>(vertex_offset_.size()) - 1;
  const int num_vertices = vertex_offset_.back();
  // a tetrahedron of an object with few partners looks up each partner's
  // vertices in the buckets of (cell, partner + 1); one of an object with
  // many (a pile of small bodies) looks up all vertices at once, in the
  // buckets of (cell, 0), which would cost one lookup per cell and partner
  bool keyed = false, unkeyed = false;
  for (int o = 0; o < num_objects; ++o) {
    const int count = partner_offset_[o + 1] - partner_offset_[o];
    keyed |= count > 0 && count <= kMaxKeyedPartners;
    unkeyed |= count > kMaxKeyedPartners;
  }
  const int per_vertex = keyed + unkeyed;
  // the insertions, vertex by vertex (keyed, then unkeyed), in blocks of
  // up to kVertexBlock vertices, each with its first insertion: the
  // vertices of the objects that are not kept, taken eight outcodes at a
  // time, and in place of each kept object its list of vertices in the
  // search box (its other outcodes are not read)
  vertex_blocks_.clear();
  auto add_blocks = [&](int begin, int end) {
    for (int b = begin; b < end; b += kVertexBlock) {
      vertex_blocks_.push_back({b, std::min(end, b + kVertexBlock), -1});
    }
  };
  int span = 0;  // (start of the objects not kept since the last kept one)
  for (int o = 0; o < num_objects && any_kept_; ++o) {
    if (!kept_[o].active) continue;
    add_blocks(span, vertex_offset_[o]);
    vertex_blocks_.push_back({0, static_cast<int>(kept_[o].hashed.size()), o});
    span = vertex_offset_[o + 1];
  }
  add_blocks(span, num_vertices);
  const int num_blocks = static_cast<int>(vertex_blocks_.size());
  const int threads = ThreadsFor(num_threads, num_blocks, 4);
  block_insertion_.resize(num_blocks + 1);
  block_insertion_[0] = 0;
  ParallelFor(threads, 0, num_blocks, [&](int k) {
    const VertexBlock& block = vertex_blocks_[k];
    const int hashed = block.kept >= 0
                           ? block.end
                           : CountZeroBytes(vertex_outcode_.data(), block.begin, block.end);
    block_insertion_[k + 1] = hashed * per_vertex;
  });
  for (int k = 0; k < num_blocks; ++k) block_insertion_[k + 1] += block_insertion_[k];
  const int num_insertions = block_insertion_[num_blocks];
  hash_.Reset(cell_size_, num_insertions);
  hash_.ResizeInsertions(num_insertions);
  ParallelFor(threads, 0, num_blocks, [&](int k) {
    const VertexBlock& block = vertex_blocks_[k];
    int i = block_insertion_[k];
    auto insert = [&](int g) {
      if (keyed) hash_.SetInsertion(i++, vertex_cell_[g], g, vertex_object_[g] + 1);
      if (unkeyed) hash_.SetInsertion(i++, vertex_cell_[g], g);
    };
    if (block.kept >= 0) {
      const int offset = vertex_offset_[block.kept];
      for (int v : kept_[block.kept].hashed) insert(offset + v);
    } else {
      ForEachZeroByte(vertex_outcode_.data(), block.begin, block.end, insert);
    }
  });
  hash_.BuildInsertions(threads);
  // what the tetrahedra test, in the hash's bucket order
  const int num_entries = hash_.num_items();
  ResizePadded(hashed_.x, num_entries);
  ResizePadded(hashed_.y, num_entries);
  ResizePadded(hashed_.z, num_entries);
  hashed_.vertex.resize(num_entries);
  hashed_.object.resize(num_entries);
  ParallelFor(ThreadsFor(num_threads, num_entries, 4096), 0, num_entries, [&](int e) {
    const int g = hash_.items()[e];
    const Eigen::Vector3d p = Position(g);
    hashed_.x[e] = p.x();
    hashed_.y[e] = p.y();
    hashed_.z[e] = p.z();
    hashed_.vertex[e] = g;
    hashed_.object[e] = vertex_object_[g];
  });
}

int PenetrationSolver::BeginSearch(std::span<const CollisionObject> objects, int num_threads) {
  const int num_objects = static_cast<int>(objects.size());
  bool any_deformable = false;  // (only rigid objects: no pair to test)
  for (const CollisionObject& object : objects) any_deformable |= !object.rigid;
  if (static_cast<int>(thread_scratch_.size()) < num_threads) thread_scratch_.resize(num_threads);
  for (ThreadScratch& scratch : thread_scratch_) {
    scratch.hits.clear();
    scratch.large_tets.clear();
    scratch.tet_tests = 0;
  }
  if (!any_deformable) return 0;
  return any_kept_ ? static_cast<int>(search_chunks_.size()) : chunk_offset_[num_objects];
}

// pass 2 of stage 1: the tetrahedra, in chunks of kChunkTets consecutive
// ones of an object in its spatial order (near each other), so that a
// chunk looks up the cells of the union of its tets' boxes once and
// gathers the partner's vertices there, and each tet tests those against
// its own box; a chunk whose union covers more than kMaxChunkCells cells
// (a deformed or stretched body) looks up tet by tet. (No vertex in the box
// of a partner object: nothing can be inside.)
void PenetrationSolver::SearchChunk(std::span<const CollisionObject> objects, int gc) {
  ThreadScratch& scratch = thread_scratch_[omp_get_thread_num()];
  HashedVertices& gathered = scratch.gathered;
  const int b = static_cast<int>(std::upper_bound(chunk_offset_.begin(), chunk_offset_.end(), gc) -
                                 chunk_offset_.begin()) -
                1;
  const CollisionObject& object_b = objects[b];
  const Positions& x = *object_b.positions;
  const int first = (gc - chunk_offset_[b]) * kChunkTets;
  const int last = gc + 1 == chunk_offset_[b + 1] ? object_b.mesh->num_tets() : first + kChunkTets;
  // the chunk's tets whose boxes meet B's search box, and the union
  // of their boxes
  std::array<SearchedTet, 2 * kChunkTets - 1> chunk;
  int chunk_size = 0;
  const double inf = std::numeric_limits<double>::infinity();
  Eigen::Vector3d union_lo = Eigen::Vector3d::Constant(inf);
  Eigen::Vector3d union_hi = Eigen::Vector3d::Constant(-inf);
  const std::vector<int>& order = object_b.mesh->spatial_tet_order();
  // (a tet whose corners all lie beyond one side of the search box is
  // outside it: told by the corners' outcodes, no positions read; so is a
  // chunk whose vertices all do, told without reading its tets: a 1.3M-tet
  // box touched by a small ball spent 2.3 ms a solve reading them)
  const std::uint8_t* outcode = vertex_outcode_.data() + vertex_offset_[b];
  {
    const int run = gc - chunk_offset_[b];
    const std::vector<int>& run_vertices = object_b.mesh->spatial_run_vertices();
    const int* run_offsets = object_b.mesh->spatial_run_vertex_offsets().data();
    std::uint8_t beyond = 0xFF;
    for (int i = run_offsets[run]; i < run_offsets[run + 1] && beyond != 0; ++i) {
      beyond &= outcode[run_vertices[i]];
    }
    if (beyond != 0) return;
  }
  for (int n = first; n < last; ++n) {
    const int t = order[n];
    SearchedTet& tet = chunk[chunk_size];
    const auto vertices = object_b.mesh->tets().row(t);
    if ((outcode[vertices[0]] & outcode[vertices[1]] & outcode[vertices[2]] &
         outcode[vertices[3]]) != 0) {
      continue;
    }
    for (int i = 0; i < 4; ++i) tet.corner[i] = x.row(vertices[i]).transpose();
    InflatedBounds(tet.corner, tet.lo, tet.hi);  // (which overlaps the search box)
    tet.t = t;
    tet.have_coordinates = false;
    union_lo = union_lo.cwiseMin(tet.lo);
    union_hi = union_hi.cwiseMax(tet.hi);
    ++chunk_size;
  }
  if (chunk_size == 0) return;
  auto test = [&](SearchedTet& tet, int e, int a) {
    TestVertexInTet(*object_b.mesh, b, tet, e, a, scratch);
  };
  // every tet tests the vertices in [lo, hi] (the region where the
  // vertices of partner entry `partner`, or of all partners (-1), can be)
  // stored under `key`; object_of(e) is the partner A of entry e, or -1 to
  // pass it over (a bucket may also hold vertices of other cells and
  // objects hashed to it, and a vertex may be met twice when two cells
  // share a bucket: duplicates are dropped in MergeHits)
  auto search = [&](const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, int partner, int key,
                    auto&& object_of) {
    const Eigen::Vector3d region_lo = union_lo.cwiseMax(lo);
    const Eigen::Vector3d region_hi = union_hi.cwiseMin(hi);
    if ((region_lo.array() > region_hi.array()).any()) return;
    const Eigen::Vector3i cell_lo = Cell(region_lo);
    const Eigen::Vector3i cell_hi = Cell(region_hi);
    // visit(e) for every entry e in `box` and the buckets of its cells
    auto for_each_in_cells = [&](const Eigen::Vector3i& from, const Eigen::Vector3i& to,
                                 const Box4& box, auto&& visit) {
      hash_.ForEachBucket(from, to, key, [&](SpatialHash::Range range) {
        box.ForEachInside(hashed_, range.begin, range.end, visit);
      });
    };
    if (CellCount(cell_lo, cell_hi) > kMaxChunkCells) {
      for (int c = 0; c < chunk_size; ++c) {  // tet by tet
        SearchedTet& tet = chunk[c];
        const Eigen::Vector3d tet_lo = tet.lo.cwiseMax(lo);
        const Eigen::Vector3d tet_hi = tet.hi.cwiseMin(hi);
        if ((tet_lo.array() > tet_hi.array()).any()) continue;
        const Eigen::Vector3i from = Cell(tet_lo);
        const Eigen::Vector3i to = Cell(tet_hi);
        if (CellCount(from, to) > kMaxTetCells) {
          scratch.large_tets.push_back({b, tet.t, partner, tet_lo, tet_hi});
          continue;
        }
        for_each_in_cells(from, to, Box4(tet_lo, tet_hi), [&](int e) {
          const int a = object_of(e);
          if (a >= 0) test(tet, e, a);
        });
      }
      return;
    }
    // gather the chunk's candidates, then test them tet by tet (the arrays
    // only grow: past the last candidate, ForEachInside reads what an
    // earlier chunk left, and masks it off; resizing them each time, with
    // NaN padding, was 8% of the chunks' instructions on the 10% cubes)
    int num_gathered = 0;
    for_each_in_cells(cell_lo, cell_hi, Box4(region_lo, region_hi), [&](int e) {
      const int a = object_of(e);
      if (a < 0) return;
      if (num_gathered + kSimdPadding >= static_cast<int>(gathered.vertex.size())) {
        const int size = 2 * (num_gathered + kSimdPadding + 1);
        for (std::vector<double>* values : {&gathered.x, &gathered.y, &gathered.z}) {
          values->resize(size);
        }
        gathered.vertex.resize(size);
        gathered.object.resize(size);
      }
      gathered.x[num_gathered] = hashed_.x[e];
      gathered.y[num_gathered] = hashed_.y[e];
      gathered.z[num_gathered] = hashed_.z[e];
      gathered.vertex[num_gathered] = e;  // (the entry in hashed_)
      gathered.object[num_gathered] = a;
      ++num_gathered;
    });
    if (num_gathered == 0) return;
    for (int c = 0; c < chunk_size; ++c) {
      SearchedTet& tet = chunk[c];
      const Eigen::Vector3d tet_lo = tet.lo.cwiseMax(lo);
      const Eigen::Vector3d tet_hi = tet.hi.cwiseMin(hi);
      if ((tet_lo.array() > tet_hi.array()).any()) continue;
      Box4(tet_lo, tet_hi).ForEachInside(gathered, 0, num_gathered, [&](int i) {
        test(tet, gathered.vertex[i], gathered.object[i]);
      });
    }
  };
  if (partner_offset_[b + 1] - partner_offset_[b] > kMaxKeyedPartners) {
    // all vertices in B's search box
    search(search_lo_[b], search_hi_[b], -1, 0, [&](int e) {
      return MayPenetrate(objects, hashed_.object[e], b) ? hashed_.object[e] : -1;
    });
    return;
  }
  for (int i = partner_offset_[b]; i < partner_offset_[b + 1]; ++i) {
    // partner A's vertices inside B lie in the overlap of their boxes
    const Partner& partner = partners_[i];
    const int a = partner.object;
    search(partner.lo, partner.hi, i, a + 1,
           [&](int e) { return hashed_.object[e] == a ? a : -1; });
  }
}

void PenetrationSolver::TestVertexInTet(const TetMesh& mesh_b, int b, SearchedTet& tet, int e,
                                        int a, ThreadScratch& scratch) const {
  if (a == b) {  // self-collision: not the tet's own vertices
    const int v = hashed_.vertex[e] - vertex_offset_[a];
    const auto vertices = mesh_b.tets().row(tet.t);
    if (v == vertices[0] || v == vertices[1] || v == vertices[2] || v == vertices[3]) return;
  }
  if (!tet.have_coordinates) {
    tet.coordinates = TetCoordinates(tet.corner[0], tet.corner[1], tet.corner[2], tet.corner[3]);
    tet.have_coordinates = true;
  }
  if (tet.coordinates.degenerate()) return;
  ++scratch.tet_tests;
  const Eigen::Vector4d l =
      tet.coordinates(Eigen::Vector3d(hashed_.x[e], hashed_.y[e], hashed_.z[e]));
  // (kBarycentricTolerance: a vertex on a face shared by two tets is inside
  // both in exact arithmetic, but rounding may put it just outside each;
  // MergeHits keeps the deepest tet)
  if (l.minCoeff() >= -kBarycentricTolerance) {
    scratch.hits.push_back({hashed_.vertex[e], b, tet.t, l});
  }
}

// Tetrahedra over more than kMaxTetCells cells (a coarse body's among fine
// ones) test the vertices in their boxes here, after the chunks: each
// would look up thousands of cells of the vertex hash. A few test every
// hashed vertex; from kMinCoarseLargeTets, the vertices go into a grid
// kCoarseCellFactor times coarser first, whose cells they look up instead
// (unless a tet covers more of those cells than hashed_ has entries over
// kEntriesPerCellLookup: then every entry again). The same vertices are
// tested either way, so the results do not depend on the path.
void PenetrationSolver::SearchLargeTets(std::span<const CollisionObject> objects) {
  large_tets_.clear();
  for (const ThreadScratch& scratch : thread_scratch_) {
    large_tets_.insert(large_tets_.end(), scratch.large_tets.begin(), scratch.large_tets.end());
  }
  const int num_large = static_cast<int>(large_tets_.size());
  if (num_large == 0) return;
  const bool coarse = num_large >= kMinCoarseLargeTets;
  if (coarse) BuildCoarseVertexHash(options_.num_threads);
  const int num_entries = hash_.num_items();
  const int threads = ThreadsFor(options_.num_threads, num_large, 4);
  if (static_cast<int>(thread_scratch_.size()) < threads) thread_scratch_.resize(threads);
  ParallelFor(
      threads, 0, num_large,
      [&](int n) {
        const LargeTet& large = large_tets_[n];
        const int b = large.object;
        const CollisionObject& object_b = objects[b];
        const Positions& x = *object_b.positions;
        SearchedTet tet;  // (its corners; its box: large.lo, large.hi)
        tet.t = large.tet;
        tet.have_coordinates = false;
        const auto vertices = object_b.mesh->tets().row(large.tet);
        for (int k = 0; k < 4; ++k) tet.corner[k] = x.row(vertices[k]).transpose();
        const int a_only = large.partner >= 0 ? partners_[large.partner].object : -1;
        ThreadScratch& scratch = thread_scratch_[omp_get_thread_num()];
        auto visit = [&](int e) {
          const int a = hashed_.object[e];
          if (a_only >= 0 ? a == a_only : MayPenetrate(objects, a, b)) {
            TestVertexInTet(*object_b.mesh, b, tet, e, a, scratch);
          }
        };
        const Box4 box(large.lo, large.hi);
        if (coarse) {
          const Eigen::Vector3i from = coarse_hash_.CellOf(large.lo);
          const Eigen::Vector3i to = coarse_hash_.CellOf(large.hi);
          if (CellCount(from, to) <= num_entries / kEntriesPerCellLookup) {
            coarse_hash_.ForEachBucket(from, to, 0, [&](SpatialHash::Range range) {
              box.ForEachInside(coarse_, range.begin, range.end,
                                [&](int c) { visit(coarse_.vertex[c]); });
            });
            return;
          }
        }
        box.ForEachInside(hashed_, 0, num_entries, visit);
      },
      Schedule::kDynamic, 4);
}

void PenetrationSolver::BuildCoarseVertexHash(int num_threads) {
  const int num_entries = hash_.num_items();
  coarse_hash_.Reset(kCoarseCellFactor * cell_size_, num_entries);
  auto cell = [&](int e) {
    return coarse_hash_.CellOf({hashed_.x[e], hashed_.y[e], hashed_.z[e]});
  };
  const int threads = ThreadsFor(num_threads, num_entries, 4096);
  coarse_hash_.ResizeInsertions(num_entries);
  ParallelFor(threads, 0, num_entries, [&](int e) { coarse_hash_.SetInsertion(e, cell(e), e); });
  coarse_hash_.BuildInsertions(threads);
  ResizePadded(coarse_.x, num_entries);
  ResizePadded(coarse_.y, num_entries);
  ResizePadded(coarse_.z, num_entries);
  coarse_.vertex.resize(num_entries);
  ParallelFor(threads, 0, num_entries, [&](int c) {
    const int e = coarse_hash_.items()[c];
    coarse_.x[c] = hashed_.x[e];
    coarse_.y[c] = hashed_.y[e];
    coarse_.z[c] = hashed_.z[e];
    coarse_.vertex[c] = e;
  });
}

// the hits of every thread, in (vertex, penetrated, tet) order, so that
// the order, and so the result, does not depend on threads: grouped by
// vertex with a counting sort, each vertex's few sorted (sorting all hits
// by comparison was serial and took 1.5% of the 100k scene's solve), or
// all sorted when they are few among many vertices (a small body on a
// large fixed one, where counting passes over every vertex); then one
// tetrahedron kept per (vertex, object): the one the vertex is deepest in
// (a vertex on a shared face or edge is inside several), and each vertex's
// range of kept hits
void PenetrationSolver::MergeHits() {
  const int num_vertices = vertex_offset_.back();
  // (the last solve's hits leave the index; all of it when the vertices
  // are others)
  if (static_cast<int>(hit_range_.size()) != num_vertices) {
    hit_range_.assign(num_vertices, {0, 0});
  } else {
    for (const Hit& hit : hits_) hit_range_[hit.vertex] = {0, 0};
  }
  int num_found = 0;
  for (const ThreadScratch& scratch : thread_scratch_) {
    num_found += static_cast<int>(scratch.hits.size());
    stats_.tet_tests += scratch.tet_tests;
  }
  hits_.resize(num_found);
  if (static_cast<long>(num_found) * kMinVerticesPerCountedHit < num_vertices) {
    int i = 0;
    for (const ThreadScratch& scratch : thread_scratch_) {
      for (const Hit& hit : scratch.hits) hits_[i++] = hit;
    }
    std::sort(hits_.begin(), hits_.end());
  } else {
    hit_place_.assign(num_vertices + 1, 0);
    for (const ThreadScratch& scratch : thread_scratch_) {
      for (const Hit& hit : scratch.hits) ++hit_place_[hit.vertex + 1];
    }
    for (int g = 0, sum = 0; g <= num_vertices; ++g) {  // (the sum in a register)
      sum += hit_place_[g];
      hit_place_[g] = sum;
    }
    for (const ThreadScratch& scratch : thread_scratch_) {
      for (const Hit& hit : scratch.hits) hits_[hit_place_[hit.vertex]++] = hit;
    }
    for (int i = 0; i < num_found;) {
      int j = i + 1;
      while (j < num_found && hits_[j].vertex == hits_[i].vertex) ++j;
      if (j - i > 1) std::sort(hits_.begin() + i, hits_.begin() + j);
      i = j;
    }
  }
  // (the kept hits move down in place)
  int kept = 0;
  for (int i = 0; i < num_found;) {
    const Hit& first = hits_[i];
    int j = i;
    int best = i;
    while (j < num_found && hits_[j].vertex == first.vertex &&
           hits_[j].penetrated == first.penetrated) {
      if (hits_[j].barycentric.minCoeff() > hits_[best].barycentric.minCoeff()) best = j;
      ++j;
    }
    std::array<int, 2>& range = hit_range_[hits_[best].vertex];
    if (range[1] == 0) range[0] = kept;  // (its first)
    hits_[kept++] = hits_[best];
    range[1] = kept;
    i = j;
  }
  hits_.resize(kept);
}

// surface triangles of every penetrated object into the triangle hash (with
// full = false only those in the region a partner can reach: an
// intersection edge lies in the box of its own object), and current vertex
// normals of those objects
void PenetrationSolver::HashSurfaces(std::span<const CollisionObject> objects, bool full) {
  Clock::time_point start = Clock::now();
  const int num_objects = static_cast<int>(objects.size());
  object_penetrated_.assign(num_objects, 0);
  for (const Hit& hit : hits_) object_penetrated_[hit.penetrated] = 1;
  surface_list_.clear();
  for (int o = 0; o < num_objects; ++o) {
    if (object_penetrated_[o]) surface_list_.push_back(o);
  }
  const int num_triangles = PlaceSurfaces(objects, full);
  const int threads = ThreadsFor(options_.num_threads, num_triangles, 128);
  if (static_cast<int>(thread_scratch_.size()) < threads) thread_scratch_.resize(threads);
  // consecutive objects to a thread: their entries (and small_'s groups)
  // are neighbours, and two threads writing either side of a cache line
  // would pass it back and forth; a few grabs per thread still balance
  const int num_surfaces = static_cast<int>(surface_list_.size());
  const int objects_per_grab = std::max(1, num_surfaces / (4 * threads));
  ParallelFor(
      threads, 0, num_surfaces, [&](int i) { HashSurface(objects, surface_list_[i]); },
      Schedule::kDynamic, objects_per_grab);
  timings_.surfaces += SecondsSince(start);
}

int PenetrationSolver::PlaceSurfaces(std::span<const CollisionObject> objects, bool full) {
  const int num_objects = static_cast<int>(objects.size());
  object_fully_hashed_.assign(num_objects, 0);
  object_small_.assign(num_objects, 0);
  object_entry_begin_.assign(num_objects, 0);
  object_entry_end_.assign(num_objects, 0);
  object_rest_begin_.assign(num_objects, 0);
  object_small_begin_.assign(num_objects, 0);
  object_rest_end_.assign(num_objects, 0);
  // each object's entries get a range the size of its whole surface, so
  // that every object can be made at once, without first counting the
  // triangles in play
  int num_entries = 0, num_small = 0;
  for (int o : surface_list_) {
    const int num_faces = static_cast<int>(objects[o].mesh->surface().rows());
    object_small_[o] = num_faces <= kSmallSurface;
    // (a kept object's closest features come from the tree kept of it:
    // its faces in play, as for stage 2, are enough)
    object_fully_hashed_[o] = object_small_[o] || (full && !kept_[o].active);
    object_entry_begin_[o] = num_entries;
    object_entry_end_[o] = num_entries;
    num_entries += num_faces;
    object_small_begin_[o] = num_small;
    if (object_small_[o]) num_small += (num_faces + 3) / 4;
  }
  triangles_.resize(num_entries);
  triangle_geometry_.resize(num_entries);
  small_.resize(num_small);
  if (++normal_round_ == 0) {  // wrapped: stamps would be ambiguous
    for (auto& stamps : normal_stamp_) std::fill(stamps.begin(), stamps.end(), 0);
    normal_round_ = 1;
  }
  normal_stamp_.resize(num_objects);
  object_triangles_.resize(num_objects);
  object_builder_.resize(num_objects);
  return num_entries;
}

// one object of surface_list_: its triangles in play (a small object's
// every triangle, a hashed one's in the region a partner can reach unless
// it is fully hashed) into its entries and, unless it is small, its hash;
// its current vertex normals (of every vertex where most of the surface is
// in play, else only of the entries' vertices: stage 2 reads the normals
// of the triangles it crosses)
void PenetrationSolver::HashSurface(std::span<const CollisionObject> objects, int o) {
  const int thread = omp_get_thread_num();
  object_builder_[o] = thread;
  const TetMesh& mesh = *objects[o].mesh;
  const Positions& x = *objects[o].positions;
  const int num_faces = static_cast<int>(mesh.surface().rows());
  std::vector<int>& faces = thread_scratch_[thread].faces;
  int num_in_play = 0;
  if (object_fully_hashed_[o]) {
    faces.resize(num_faces);
    std::iota(faces.begin(), faces.end(), 0);
    num_in_play = num_faces;
  } else if (kept_[o].active) {
    // among the faces of the searched chunks (a face in play meets the
    // search box, and so does the box of its tet's chunk), in order
    const KeptObject& kept = kept_[o];
    faces.clear();
    for (int run : kept.searched) {
      faces.insert(faces.end(), kept.run_faces.begin() + kept.run_face_offset[run],
                   kept.run_faces.begin() + kept.run_face_offset[run + 1]);
    }
    std::sort(faces.begin(), faces.end());
    const std::uint8_t* outcode = vertex_outcode_.data() + vertex_offset_[o];
    const int* corner = mesh.surface().data();
    for (int i = 0; i < static_cast<int>(faces.size()); ++i) {
      faces[num_in_play] = faces[i];
      num_in_play += CornersInBox(outcode, corner + 3 * faces[i]);
    }
  } else {
    faces.resize(num_faces);
    // (TriangleInRegion's test, written for every face: branch-free)
    const std::uint8_t* outcode = vertex_outcode_.data() + vertex_offset_[o];
    const int* corner = mesh.surface().data();
    for (int f = 0; f < num_faces; ++f) {
      faces[num_in_play] = f;
      num_in_play += CornersInBox(outcode, corner + 3 * f);
    }
  }
  faces.resize(num_in_play);
  object_entry_end_[o] = object_entry_begin_[o] + static_cast<int>(faces.size());
  long num_pairs = 0;      // (cell, triangle) pairs a hashed object's table will hold
  if (object_small_[o]) {  // every face, in order (fully hashed)
    SmallTriangleGroup* groups = &small_[object_small_begin_[o]];
    for (int f = 0; f < num_faces; ++f) {
      MakeSmallTriangle(x, mesh.surface(), f, groups[f / 4], f % 4);
    }
    for (int f = num_faces; f % 4 != 0; ++f) {  // the last group's lanes past the faces
      for (int k = 0; k < 3; ++k) {
        groups[f / 4].lo[k][f % 4] = std::numeric_limits<double>::quiet_NaN();
        groups[f / 4].hi[k][f % 4] = std::numeric_limits<double>::quiet_NaN();
      }
    }
  } else {
    for (int n = 0; n < static_cast<int>(faces.size()); ++n) {
      const int index = object_entry_begin_[o] + n;
      TriangleGeometry& geometry = triangle_geometry_[index];
      MakeTriangle(objects, o, faces[n], triangles_[index], geometry);
      const long cells = CellCount(geometry.cell_lo, geometry.cell_hi);
      if (cells <= kMaxTriangleCells) num_pairs += cells;
    }
  }
  // (closest features need neither the hash nor the normals: their queries
  // go through the object's box tree)
  if (options_.method == DepthMethod::kClosest) return;
  if (!object_small_[o]) {  // (a small one is tested from the list)
    // a table twice the size of the (cell, triangle) pairs: few buckets
    // shared by cells, whose entries a query would test too
    object_triangles_[o].hash.Reset(cell_size_, static_cast<int>(num_pairs));
    object_triangles_[o].large.clear();
    for (int index = object_entry_begin_[o]; index < object_entry_end_[o]; ++index) {
      InsertTriangle(index);
    }
    BuildTriangleHash(o);
  }
  if (2 * static_cast<int>(faces.size()) > num_faces) {
    ComputeVertexNormals(x, mesh.surface(), normals_[o]);
    return;
  }
  normals_[o].resize(mesh.num_vertices(), 3);
  std::vector<std::uint32_t>& stamp = normal_stamp_[o];
  stamp.resize(mesh.num_vertices(), 0);
  for (int f : faces) {
    for (int k = 0; k < 3; ++k) {
      const int v = mesh.surface()(f, k);
      if (stamp[v] == normal_round_) continue;
      stamp[v] = normal_round_;
      normals_[o].row(v) = VertexNormal(mesh, x, v).transpose();
    }
  }
}

void PenetrationSolver::AddRemainingTriangles(std::span<const CollisionObject> objects, int b) {
  if (object_fully_hashed_[b] || kept_[b].active) return;  // (kept: its tree of all faces)
  object_fully_hashed_[b] = 1;
  const Triangles& surface = objects[b].mesh->surface();
  object_rest_begin_[b] = static_cast<int>(triangles_.size());
  for (int f = 0; f < surface.rows(); ++f) {
    if (!TriangleInRegion(objects, b, f, TriangleRegion::kOutside)) continue;
    TriangleEntry entry;
    TriangleGeometry geometry;
    MakeTriangle(objects, b, f, entry, geometry);
    triangles_.push_back(entry);
    triangle_geometry_.push_back(geometry);
  }
  object_rest_end_[b] = static_cast<int>(triangles_.size());
}

void PenetrationSolver::BuildTree(int b) {
  ObjectTriangles& hashed = object_triangles_[b];
  hashed.tree_lo.clear();
  hashed.tree_hi.clear();
  hashed.tree_entry.clear();
  for (const auto& [begin, end] :
       {std::array<int, 2>{object_entry_begin_[b], object_entry_end_[b]},
        std::array<int, 2>{object_rest_begin_[b], object_rest_end_[b]}}) {
    for (int index = begin; index < end; ++index) {
      hashed.tree_lo.push_back(triangles_[index].lo);
      hashed.tree_hi.push_back(triangles_[index].hi);
      hashed.tree_entry.push_back(index);
    }
  }
  hashed.tree.Build(hashed.tree_lo, hashed.tree_hi);
}

bool PenetrationSolver::TriangleInRegion(std::span<const CollisionObject> objects, int object,
                                         int f, TriangleRegion region) const {
  if (region == TriangleRegion::kAll) return true;
  const Triangles& surface = objects[object].mesh->surface();
  // in the search box, told by the vertices' outcodes: no positions read
  const std::uint8_t* outcode = vertex_outcode_.data() + vertex_offset_[object];
  const bool inside = CornersInBox(outcode, &surface(f, 0));
  return inside == (region == TriangleRegion::kInside);
}

void PenetrationSolver::MakeTriangle(std::span<const CollisionObject> objects, int object, int f,
                                     TriangleEntry& entry, TriangleGeometry& geometry) const {
  const Positions& x = *objects[object].positions;
  const Triangles& surface = objects[object].mesh->surface();
  for (int k = 0; k < 3; ++k) geometry.corner[k] = x.row(surface(f, k)).transpose();
  InflatedBounds(geometry.corner, entry.lo, entry.hi);
  entry.object = object;
  entry.face = f;
  geometry.edge[0] = geometry.corner[1] - geometry.corner[0];
  geometry.edge[1] = geometry.corner[2] - geometry.corner[0];
  geometry.edge_lengths = geometry.edge[0].norm() * geometry.edge[1].norm();
  geometry.cell_lo = Cell(entry.lo);
  geometry.cell_hi = Cell(entry.hi);
}

void PenetrationSolver::MakeSmallTriangle(const Positions& x, const Triangles& surface, int f,
                                          SmallTriangleGroup& group, int lane) {
  // (the arithmetic of MakeTriangle)
  Eigen::Vector3d corner[3], lo, hi;
  for (int k = 0; k < 3; ++k) corner[k] = x.row(surface(f, k)).transpose();
  InflatedBounds(corner, lo, hi);
  const Eigen::Vector3d edge0 = corner[1] - corner[0];
  const Eigen::Vector3d edge1 = corner[2] - corner[0];
  for (int k = 0; k < 3; ++k) {
    group.lo[k][lane] = lo[k];
    group.hi[k][lane] = hi[k];
    group.corner[k][lane] = corner[0][k];
    group.edge0[k][lane] = edge0[k];
    group.edge1[k][lane] = edge1[k];
  }
  group.edge_lengths[lane] = edge0.norm() * edge1.norm();
}

void PenetrationSolver::InsertTriangle(int index) {
  const TriangleGeometry& geometry = triangle_geometry_[index];
  ObjectTriangles& hashed = object_triangles_[triangles_[index].object];
  if (CellCount(geometry.cell_lo, geometry.cell_hi) > kMaxTriangleCells) {
    hashed.large.push_back(index);
    return;
  }
  for (int k = geometry.cell_lo.z(); k <= geometry.cell_hi.z(); ++k) {
    for (int j = geometry.cell_lo.y(); j <= geometry.cell_hi.y(); ++j) {
      for (int i = geometry.cell_lo.x(); i <= geometry.cell_hi.x(); ++i) {
        hashed.hash.Insert({i, j, k}, index);
      }
    }
  }
}

void PenetrationSolver::BuildTriangleHash(int object) {
  ObjectTriangles& hashed = object_triangles_[object];
  hashed.large_lo.clear();
  hashed.large_hi.clear();
  if (static_cast<int>(hashed.large.size()) > kMaxLargeListed) {
    for (int index : hashed.large) {
      hashed.large_lo.push_back(triangles_[index].lo);
      hashed.large_hi.push_back(triangles_[index].hi);
    }
  }
  hashed.large_tree.Build(hashed.large_lo, hashed.large_hi);  // (empty if few)
  hashed.hash.Build();
  const int num_entries = hashed.hash.num_items();
  const std::span<const int> items = hashed.hash.items();
  double* lo[3];
  double* hi[3];
  for (int k = 0; k < 3; ++k) {
    ResizePadded(hashed.boxes.lo[k], num_entries);
    ResizePadded(hashed.boxes.hi[k], num_entries);
    lo[k] = hashed.boxes.lo[k].data();
    hi[k] = hashed.boxes.hi[k].data();
  }
  for (int e = 0; e < num_entries; ++e) {  // (one pass: an entry read once)
    const TriangleEntry& entry = triangles_[items[e]];
    for (int k = 0; k < 3; ++k) {
      lo[k][e] = entry.lo[k];
      hi[k][e] = entry.hi[k];
    }
  }
}

// stages 2 and 3, point by point: for every colliding point p and
// neighbour q outside B, the crossing of the edge q -> p with B's surface
// nearest q and B's smooth normal there (stage 2); from the point's
// crossings, its depth and direction (stage 3: a border point). One pass:
// a point's crossings are used as soon as they are found, never stored.
void PenetrationSolver::ComputeBorderPoints(std::span<const CollisionObject> objects) {
  Clock::time_point start = Clock::now();
  const int num_hits = static_cast<int>(hits_.size());
  const int num_threads = std::max(1, options_.num_threads);
  depth_.resize(num_hits);
  direction_.resize(num_hits);
  source_.resize(num_hits);
  layer_.assign(num_hits, -1);
  // a crossing closer than this to p means p is on the surface: depth 0
  const double on_surface = 1e-9 * length_scale_;
  // per thread: the query in which each triangle entry was last tested
  if (static_cast<int>(thread_scratch_.size()) < num_threads) thread_scratch_.resize(num_threads);
  for (int i = 0; i < num_threads; ++i) {
    // (stamps of earlier solves are below the next query: cleared only
    // before they could wrap; a solve makes fewer than 2^31 queries)
    ThreadScratch& scratch = thread_scratch_[i];
    if (scratch.query >= 0x80000000u) {
      std::fill(scratch.seen.begin(), scratch.seen.end(), 0);
      scratch.query = 0;
    }
    if (scratch.seen.size() < triangles_.size()) scratch.seen.resize(triangles_.size(), 0);
    scratch.edges = 0;
    scratch.triangle_tests = 0;
    scratch.candidates.clear();
  }
  auto resolve = [&](int h) {  // stages 2 and 3 for hit h
    ThreadScratch& scratch = thread_scratch_[omp_get_thread_num()];
    const Hit& hit = hits_[h];
    const int a = vertex_object_[hit.vertex];
    const int b = hit.penetrated;
    const int v = hit.vertex - vertex_offset_[a];
    const TetMesh& mesh_a = *objects[a].mesh;
    const Triangles& surface_b = objects[b].mesh->surface();
    const Eigen::Vector3d p = Position(hit.vertex);
    // stage 3's sums over the crossings, and the nearest crossing's normal
    double weight_sum = 0.0;
    double depth_sum = 0.0;
    Eigen::Vector3d normal_sum = Eigen::Vector3d::Zero();
    Eigen::Vector3d nearest_normal = Eigen::Vector3d::Zero();
    double nearest_distance = std::numeric_limits<double>::infinity();
    bool any_crossing = false;
    // p's neighbours inside B: if p is a border point, the candidates for
    // the first propagation layer (those that are not border points too)
    std::vector<int>& candidates = scratch.candidates;
    const size_t num_listed = candidates.size();
    // the face of triangle entry `index` of B: a small object's entries are
    // its faces in order, and their entries are not read (the four-wide
    // tests read small_): in a pile of 2400 spheres, loading the entry for
    // its face was the most frequent cache miss of stage 2
    const bool small = object_small_[b];
    const int entry_begin = object_entry_begin_[b];
    auto face_of = [&](int index) { return small ? index - entry_begin : triangles_[index].face; };
    for (int n = mesh_a.adjacency_offsets()[v]; n < mesh_a.adjacency_offsets()[v + 1]; ++n) {
      const int q_local = mesh_a.adjacency()[n];
      const int q_global = vertex_offset_[a] + q_local;
      const int q_hit = FindHit(q_global, b);
      if (q_hit >= 0) {  // q is inside B too: not an intersection edge
        candidates.push_back(q_hit);
        continue;
      }
      ++scratch.edges;
      const Eigen::Vector3d q = Position(q_global);
      const Eigen::Vector3d dir = p - q;
      const double dir_length = dir.norm();
      double best_t = std::numeric_limits<double>::infinity();
      int best_entry = -1;
      double best_u = 0.0, best_v = 0.0;
      const Eigen::Vector3d ends[2] = {q, p};
      Eigen::Vector3d segment_lo, segment_hi;
      InflatedBounds(ends, segment_lo, segment_hi);
      // the crossing with entry `index` at q + t dir, (u, w) in the
      // triangle: the nearest to q is kept, ties broken by entry for
      // determinism
      auto consider = [&](int index, double t, double u, double w) {
        if (a == b) {  // self-collision: the edge's own triangles do not count
          for (int k = 0; k < 3; ++k) {
            const int c = surface_b(face_of(index), k);
            if (c == v || c == q_local) return;
          }
        }
        if (t < best_t || (t == best_t && index < best_entry)) {
          best_t = t;
          best_entry = index;
          best_u = u;
          best_v = w;
        }
      };
      auto test_triangle = [&](int index) {
        ++scratch.triangle_tests;
        const TriangleGeometry& triangle = triangle_geometry_[index];
        double t, u, w;
        if (SegmentTriangle(q, dir, dir_length, triangle.corner[0], triangle.edge[0],
                            triangle.edge[1], triangle.edge_lengths, t, u, w)) {
          consider(index, t, u, w);
        }
      };
      if (small) {
        // a small object's triangles are all in its list, none in the
        // grid: tested four at a time, box and crossing
        const int num_faces = object_entry_end_[b] - entry_begin;
        const SmallTriangleGroup* groups = &small_[object_small_begin_[b]];
        const Box4 segment_box(segment_lo, segment_hi);
        for (int g = 0; g < (num_faces + 3) / 4; ++g) {
          const SmallTriangleGroup& group = groups[g];
          const unsigned overlapping = segment_box.Overlapping(group.lo, group.hi);
          if (overlapping == 0) continue;
          scratch.triangle_tests += std::popcount(overlapping);
          Double4 t, u, w;
          const unsigned crossed =
              overlapping & SegmentTriangles4(q, dir, dir_length, group.corner, group.edge0,
                                              group.edge1, group.edge_lengths, t, u, w);
          for (unsigned bits = crossed; bits != 0; bits &= bits - 1) {
            const int lane = std::countr_zero(bits);
            consider(entry_begin + 4 * g + lane, t[lane], u[lane], w[lane]);
          }
        }
      } else {
        const ObjectTriangles& hashed = object_triangles_[b];
        if (hashed.large_tree.num_items() > 0) [[unlikely]] {
          hashed.large_tree.Overlapping(segment_lo, segment_hi,
                                        [&](int item) { test_triangle(hashed.large[item]); });
        } else {
          for (int index : hashed.large) {
            const TriangleEntry& entry = triangles_[index];
            if (BoxesOverlap(entry.lo, entry.hi, segment_lo, segment_hi)) test_triangle(index);
          }
        }
        // the boxes of the buckets of the segment's cells, four at a
        // time; a triangle covering several of those cells is met in
        // each: tested once per query
        const std::uint32_t query = ++scratch.query;
        Eigen::Vector3i lo = hashed.hash.CellOf(segment_lo);
        Eigen::Vector3i hi = hashed.hash.CellOf(segment_hi);
        // a segment across too many cells (kEntriesPerCellLookup): every
        // entry in one pass instead, which tests the same triangles (one
        // whose box meets the segment's shares a cell with it)
        const bool every_entry =
            CellCount(lo, hi) > hashed.hash.num_items() / kEntriesPerCellLookup;
        if (every_entry) hi = lo;
        const Box4 segment_box(segment_lo, segment_hi);
        const std::span<const int> items = hashed.hash.items();
        for (int k = lo.z(); k <= hi.z(); ++k) {
          for (int j = lo.y(); j <= hi.y(); ++j) {
            for (int i = lo.x(); i <= hi.x(); ++i) {
              const SpatialHash::Range range = every_entry
                                                   ? SpatialHash::Range{0, hashed.hash.num_items()}
                                                   : hashed.hash.Find({i, j, k});
              for (int e = range.begin; e < range.end; e += 4) {
                for (unsigned bits =
                         segment_box.Overlapping(hashed.boxes.lo, hashed.boxes.hi, e, range.end);
                     bits != 0; bits &= bits - 1) {
                  const int index = items[e + std::countr_zero(bits)];
                  if (scratch.seen[index] == query) continue;
                  scratch.seen[index] = query;
                  test_triangle(index);
                }
              }
            }
          }
        }
      }
      if (best_entry < 0) continue;
      const int f = face_of(best_entry);
      const Eigen::Vector3d crossing = q + best_t * dir;
      // smooth normal: barycentric interpolation of the vertex normals, or
      // the face normal where they cancel
      Eigen::Vector3d normal;
      auto face_normal = [&]() -> Eigen::Vector3d {
        if (small) {
          const SmallTriangleGroup& group = small_[object_small_begin_[b] + f / 4];
          const int lane = f % 4;
          return Lane(group.edge0, lane).cross(Lane(group.edge1, lane));
        }
        const TriangleGeometry& triangle = triangle_geometry_[best_entry];
        return triangle.edge[0].cross(triangle.edge[1]);
      };
      if (!SmoothNormal(normals_[b].row(surface_b(f, 0)).transpose(),
                        normals_[b].row(surface_b(f, 1)).transpose(),
                        normals_[b].row(surface_b(f, 2)).transpose(), best_u, best_v, face_normal,
                        normal)) {
        continue;
      }
      // stage 3: w_i = 1 / |x_i - p|^2 (method.md)
      const Eigen::Vector3d to_crossing = crossing - p;
      const double distance = to_crossing.norm();
      if (distance < nearest_distance) {
        nearest_distance = distance;
        nearest_normal = normal;
      }
      any_crossing = true;
      if (distance < on_surface) continue;
      const double w = 1.0 / (distance * distance);
      weight_sum += w;
      depth_sum += w * to_crossing.dot(normal);
      normal_sum += w * normal;
    }
    if (!any_crossing) {  // not a border point (or no crossing found)
      candidates.resize(num_listed);
      return;
    }
    if (nearest_distance < on_surface || weight_sum == 0.0) {
      depth_[h] = 0.0;
      direction_[h] = nearest_normal;
    } else {
      depth_[h] = std::max(0.0, depth_sum / weight_sum);
      const double normal_length = normal_sum.norm();
      direction_[h] = normal_length > 1e-12 * weight_sum
                          ? Eigen::Vector3d(normal_sum / normal_length)
                          : nearest_normal;
    }
    source_[h] = DepthSource::kBorder;
    layer_[h] = 0;
  };
  const int threads = ThreadsFor(num_threads, num_hits, 16);
  if (threads == 1) {
    for (int h = 0; h < num_hits; ++h) resolve(h);
  } else {
    // each thread starts with the hits into the objects whose triangles it
    // made (HashSurfaces): their hash, boxes, geometry and normals are in
    // its core's cache
    GroupByKey(
        threads,
        [&](auto emit) {
          for (int h = 0; h < num_hits; ++h) {
            emit(object_builder_[hits_[h].penetrated] % threads, h);
          }
        },
        hit_group_offset_, hit_order_);
    // about sixteen grabs per thread, of 2 to 16 points: one thread's last
    // grab ends while the other waits (how far apart two threads finished,
    // median over the solves: 10% cubes 1.9-3.9 us with grabs of 16, 0.7
    // with 3 or 4; 70% cubes 3.5 and 1.4 with 12)
    const int grab = std::clamp(num_hits / (16 * threads), 2, 16);
    ParallelForGroups(
        threads, hit_group_offset_, [&](int i) { resolve(hit_order_[i]); }, grab);
  }
  int edges = 0;
  for (int i = 0; i < num_threads; ++i) {
    edges += thread_scratch_[i].edges;
    stats_.triangle_tests += thread_scratch_[i].triangle_tests;
  }
  stats_.intersection_edges = edges;
  timings_.intersect += SecondsSince(start);
}

// stage 4: propagation to inner points, each layer from earlier layers only
void PenetrationSolver::Propagate(std::span<const CollisionObject> objects) {
  Clock::time_point start = Clock::now();
  const int num_threads = std::max(1, options_.num_threads);
  constexpr int kInNextLayer = -2;
  if (static_cast<int>(thread_scratch_.size()) < num_threads) thread_scratch_.resize(num_threads);
  // the next layer: the points without a value next to a point with one
  // (the first from the border points; later ones from the candidates the
  // layer's computation listed), in index order
  auto add_to_next_layer = [&](int h) {
    if (layer_[h] != -1) return;
    layer_[h] = kInNextLayer;
    next_frontier_.push_back(h);
  };
  // the first layer: the neighbours of border points that stage 2 listed
  next_frontier_.clear();
  for (int i = 0; i < num_threads; ++i) {
    for (int h : thread_scratch_[i].candidates) add_to_next_layer(h);
  }
  const double coincident = 1e-9 * length_scale_;
  int layer = 0;
  while (!next_frontier_.empty()) {
    ++layer;
    std::sort(next_frontier_.begin(), next_frontier_.end());
    const int layer_size = static_cast<int>(next_frontier_.size());
    const int threads = ThreadsFor(num_threads, layer_size, kMinLayerPointsPerThread);
    for (int i = 0; i < threads; ++i) thread_scratch_[i].candidates.clear();
    // each point of the layer from its neighbours of earlier layers; a
    // point that gets a value lists its neighbours without one (those of
    // this layer too: they stay without one if their directions cancel)
    ParallelFor(threads, 0, layer_size, [&](int i) {
      const int h = next_frontier_[i];
      const int g = hits_[h].vertex;
      const int a = vertex_object_[g];
      const int v = g - vertex_offset_[a];
      const TetMesh& mesh = *objects[a].mesh;
      const Eigen::Vector3d p = Position(g);
      double weight_sum = 0.0;
      double depth_sum = 0.0;
      Eigen::Vector3d direction_sum = Eigen::Vector3d::Zero();
      int copy_from = -1;
      std::vector<int>& candidates = thread_scratch_[omp_get_thread_num()].candidates;
      const size_t num_listed = candidates.size();
      for (int n = mesh.adjacency_offsets()[v]; n < mesh.adjacency_offsets()[v + 1]; ++n) {
        const int j_global = vertex_offset_[a] + mesh.adjacency()[n];
        const int j = FindHit(j_global, hits_[h].penetrated);
        if (j < 0) continue;
        if (layer_[j] < 0) {  // a later layer, or this one
          candidates.push_back(j);
          continue;
        }
        Eigen::Vector3d to_neighbour = Position(j_global) - p;
        double distance_sq = to_neighbour.squaredNorm();
        if (distance_sq < coincident * coincident) {
          if (copy_from < 0) copy_from = j;
          continue;
        }
        // mu_j = 1 / |p_j - p|^2 (method.md, stage 4)
        double mu = 1.0 / distance_sq;
        weight_sum += mu;
        depth_sum += mu * (to_neighbour.dot(direction_[j]) + depth_[j]);
        direction_sum += mu * direction_[j];
      }
      direction_[h] = Eigen::Vector3d::Zero();  // (none: no value yet)
      if (copy_from >= 0) {
        depth_[h] = depth_[copy_from];
        direction_[h] = direction_[copy_from];
      } else if (weight_sum > 0.0) {
        depth_[h] = std::max(0.0, depth_sum / weight_sum);
        const double length = direction_sum.norm();
        // (directions that cancel leave the point without a value)
        if (length > 1e-12 * weight_sum) direction_[h] = direction_sum / length;
      }
      source_[h] = DepthSource::kPropagated;
      if (direction_[h].squaredNorm() == 0.0) candidates.resize(num_listed);
    });
    for (int h : next_frontier_) {
      layer_[h] = direction_[h].squaredNorm() > 0.0 ? layer : -1;
    }
    next_frontier_.clear();
    for (int i = 0; i < threads; ++i) {
      for (int h : thread_scratch_[i].candidates) add_to_next_layer(h);
    }
  }
  stats_.layers = layer;
  timings_.propagate += SecondsSince(start);
}

bool PenetrationSolver::ClosestSurfacePoint(std::span<const CollisionObject> objects, int b,
                                            const Eigen::Vector3d& p, int exclude,
                                            Eigen::Vector3d& closest) const {
  const Triangles& surface = objects[b].mesh->surface();
  double best = std::numeric_limits<double>::infinity();
  int best_face = -1;
  // (of triangles equally near, the lowest face: the result does not
  // depend on the order the search meets them in, the tree's)
  // face f with box [lo, hi]; corners() gives its corners
  // (box_point: p in the frame of the box, the body frame of a framed
  // object's kept boxes)
  auto test_face = [&](int f, const Eigen::Vector3d& lo, const Eigen::Vector3d& hi,
                       const Eigen::Vector3d& box_point, auto&& corners) {
    // (a triangle whose box is farther than the best cannot be nearer: on
    // a coarse box pressed into a fine body, most queries test every one
    // of its large faces)
    if (BoxDistance2(lo, hi, box_point) > best) return;
    if (exclude >= 0 &&
        (surface(f, 0) == exclude || surface(f, 1) == exclude || surface(f, 2) == exclude)) {
      return;
    }
    const std::array<Eigen::Vector3d, 3> corner = corners();
    Eigen::Vector3d c = ClosestPointOnTriangle(p, corner[0], corner[1], corner[2]);
    double d = (c - p).squaredNorm();
    if (d < best || (d == best && f < best_face)) {
      best = d;
      best_face = f;
      closest = c;
    }
  };
  // face f's corners from the object's positions (a small or kept object's
  // faces have no entry)
  const Positions& x = *objects[b].positions;
  auto face_corners = [&](int f) {
    return std::array<Eigen::Vector3d, 3>{x.row(surface(f, 0)).transpose(),
                                          x.row(surface(f, 1)).transpose(),
                                          x.row(surface(f, 2)).transpose()};
  };
  auto test = [&](int index) {  // a triangle entry
    const TriangleEntry& entry = triangles_[index];
    test_face(entry.face, entry.lo, entry.hi, p, [&] {
      const TriangleGeometry& triangle = triangle_geometry_[index];
      return std::array<Eigen::Vector3d, 3>{triangle.corner[0], triangle.corner[1],
                                            triangle.corner[2]};
    });
  };
  if (object_small_[b]) {  // (its boxes in small_, no entries)
    const SmallTriangleGroup* groups = &small_[object_small_begin_[b]];
    for (int f = 0; f < object_entry_end_[b] - object_entry_begin_[b]; ++f) {
      const SmallTriangleGroup& group = groups[f / 4];
      const int lane = f % 4;
      test_face(f, Lane(group.lo, lane), Lane(group.hi, lane), p, [&] { return face_corners(f); });
    }
    return std::isfinite(best);
  }
  // the object's box tree over all its triangles: kept, if it is fixed or
  // framed, or built by ComputeClosest (nearer boxes first, those farther
  // than the best passed over); else every triangle
  if (kept_[b].active) {
    const KeptObject& kept = kept_[b];
    // (framed: distances are the same in the body frame, and the kept
    // boxes' growth covers the rounding of p taken there)
    const Eigen::Vector3d q = kept.ToBody(p);
    kept.faces.Nearest(q, best, [&](int f) {
      test_face(f, kept.face_lo[f], kept.face_hi[f], q, [&] { return face_corners(f); });
    });
  } else if (closest_queries_[b] >= kMinTreeQueries) {
    const ObjectTriangles& hashed = object_triangles_[b];
    hashed.tree.Nearest(p, best, [&](int item) { test(hashed.tree_entry[item]); });
  } else {
    for (int entry = object_entry_begin_[b]; entry < object_entry_end_[b]; ++entry) test(entry);
    for (int entry = object_rest_begin_[b]; entry < object_rest_end_[b]; ++entry) test(entry);
  }
  return std::isfinite(best);
}

// closest features: for every point without a value (fallback) or all points
void PenetrationSolver::ComputeClosest(std::span<const CollisionObject> objects, bool all) {
  Clock::time_point start = Clock::now();
  const int num_hits = static_cast<int>(hits_.size());
  if (all) {
    depth_.resize(num_hits);
    direction_.resize(num_hits);
    source_.resize(num_hits);
    layer_.assign(num_hits, -1);
  }
  const DepthSource source = all ? DepthSource::kClosest : DepthSource::kFallback;
  frontier_.clear();  // (free after stage 4): the points without a value
  tree_objects_.clear();
  closest_queries_.assign(objects.size(), 0);
  for (int h = 0; h < num_hits; ++h) {
    if (layer_[h] >= 0) continue;
    frontier_.push_back(h);
    const int b = hits_[h].penetrated;
    AddRemainingTriangles(objects, b);
    // a box tree for the objects with enough queries to pay for it (a
    // coarse box's one corner in a fine ball is cheaper searched whole)
    if (++closest_queries_[b] == kMinTreeQueries && !object_small_[b] && !kept_[b].active) {
      tree_objects_.push_back(b);
    }
  }
  const int num_trees = static_cast<int>(tree_objects_.size());
  ParallelFor(
      ThreadsFor(options_.num_threads, num_trees, 1), 0, num_trees,
      [&](int i) { BuildTree(tree_objects_[i]); }, Schedule::kDynamic, 1);
  const int num_pending = static_cast<int>(frontier_.size());
  ParallelFor(
      ThreadsFor(options_.num_threads, num_pending, 16), 0, num_pending,
      [&](int i) {
        const int h = frontier_[i];
        const int g = hits_[h].vertex;
        const int a = vertex_object_[g];
        const int b = hits_[h].penetrated;
        const Eigen::Vector3d p = Position(g);
        Eigen::Vector3d closest;
        int exclude = a == b ? g - vertex_offset_[a] : -1;
        if (!ClosestSurfacePoint(objects, b, p, exclude, closest)) return;
        Eigen::Vector3d to_surface = closest - p;
        double distance = to_surface.norm();
        depth_[h] = distance;
        if (distance > 0.0) {
          direction_[h] = to_surface / distance;
        } else {
          // on the surface: the way out is B's outward normal there; take the
          // containing tet's centroid as the inside
          const auto tet = objects[b].mesh->tets().row(hits_[h].tet);
          Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
          for (int c = 0; c < 4; ++c) {
            centroid += objects[b].positions->row(tet[c]).transpose() / 4.0;
          }
          Eigen::Vector3d out = p - centroid;
          direction_[h] =
              out.norm() > 0.0 ? Eigen::Vector3d(out.normalized()) : Eigen::Vector3d::UnitZ();
        }
        source_[h] = source;
        layer_[h] = std::numeric_limits<int>::max();
      },
      Schedule::kDynamic, 16);
  timings_.closest += SecondsSince(start);
}

void PenetrationSolver::CollectResults(std::span<const CollisionObject> /*objects*/) {
  results_.clear();
  double depth_sum = 0.0;
  for (size_t h = 0; h < hits_.size(); ++h) {
    if (layer_[h] < 0) {
      ++stats_.unresolved;
      continue;
    }
    const Hit& hit = hits_[h];
    PenetrationResult result;
    result.object = vertex_object_[hit.vertex];
    result.vertex = hit.vertex - vertex_offset_[result.object];
    result.penetrated = hit.penetrated;
    result.tet = hit.tet;
    result.barycentric = hit.barycentric;
    result.depth = depth_[h];
    result.direction = direction_[h];
    result.source = source_[h];
    results_.push_back(result);
    depth_sum += result.depth;
    stats_.max_depth = std::max(stats_.max_depth, result.depth);
    switch (result.source) {
      case DepthSource::kBorder:
        ++stats_.border;
        break;
      case DepthSource::kPropagated:
        ++stats_.propagated;
        break;
      case DepthSource::kFallback:
        ++stats_.fallback;
        break;
      case DepthSource::kClosest:
        ++stats_.closest;
        break;
    }
  }
  stats_.colliding = static_cast<int>(results_.size());
  stats_.mean_depth = results_.empty() ? 0.0 : depth_sum / static_cast<double>(results_.size());
}

}  // namespace tetcosim
