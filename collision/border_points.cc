// Stages 2 and 3 of the penetration solver: the border points' intersection
// edges, their crossings with the penetrated surface, and the border
// points' depths and directions.

#include "collision/penetration.h"

#include <omp.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>
#include <span>

#include "collision/geometry.h"
#include "collision/penetration_internal.h"
#include "collision/simd4.h"
#include "mesh/group_by_key.h"
#include "mesh/parallel_for.h"
#include "mesh/vector_room.h"

namespace tetcosim {
namespace {

// SegmentTriangle (geometry.h) for four triangles by coordinate (lane j of
// corner[k], edge0[k], edge1[k] and edge_lengths: Surfaces::Geometry's
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

}  // namespace

// stages 2 and 3, point by point: for every colliding point p and
// neighbour q outside B, the crossing of the edge q -> p with B's surface
// nearest q and B's smooth normal there (stage 2); from the point's
// crossings, its depth and direction (stage 3: a border point). One pass:
// a point's crossings are used as soon as they are found, never stored.
void PenetrationSolver::ComputeBorderPoints(std::span<const CollisionObject> objects) {
  Clock::time_point start = Clock::now();
  const int num_hits = static_cast<int>(colliding_.hits().size());
  const int num_threads = std::max(1, options_.num_threads);
  ResizeWithRoom(depth_, num_hits);
  ResizeWithRoom(direction_, num_hits);
  ResizeWithRoom(source_, num_hits);
  AssignWithRoom(layer_, num_hits, -1);
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
    if (static_cast<int>(scratch.seen.size()) < surfaces_.num_entries()) {
      scratch.seen.resize(surfaces_.num_entries(), 0);
    }
    scratch.edges = 0;
    scratch.triangle_tests = 0;
  }
  // (room in every thread for all the candidates of a layer, whoever lists
  // them, and for those of a point that turns out not to be a border point:
  // penetration_internal.h)
  ClearForAnyShare(std::span<ThreadScratch>(thread_scratch_), &ThreadScratch::candidates,
                   max_degree_);
  auto resolve = [&](int h) {  // stages 2 and 3 for hit h
    ThreadScratch& scratch = thread_scratch_[omp_get_thread_num()];
    const Hit& hit = colliding_.hits()[h];
    const int a = vertices_.object[hit.vertex];
    const int b = hit.penetrated;
    const int v = hit.vertex - vertices_.offset[a];
    const TetMesh& mesh_a = *objects[a].mesh;
    const Triangles& surface_b = objects[b].mesh->surface();
    const Eigen::Vector3d p = Position(hit.vertex);
    // stage 3's sums over the crossings
    BorderPointSums sums(on_surface);
    // p's neighbours inside B: if p is a border point, the candidates for
    // the first propagation layer (those that are not border points too)
    std::vector<int>& candidates = scratch.candidates;
    const size_t num_listed = candidates.size();
    // the face of triangle entry `index` of B: a small object's entries are
    // its faces in order, and their entries are not read (the four-wide
    // tests read its groups): in a pile of 2400 spheres, loading the entry for
    // its face was the most frequent cache miss of stage 2
    const bool small = surfaces_.small(b);
    const int entry_begin = surfaces_.entry_begin(b);
    auto face_of = [&](int index) {
      return small ? index - entry_begin : surfaces_.entry(index).face;
    };
    for (int n = mesh_a.adjacency_offsets()[v]; n < mesh_a.adjacency_offsets()[v + 1]; ++n) {
      const int q_local = mesh_a.adjacency()[n];
      const int q_global = vertices_.offset[a] + q_local;
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
        const Surfaces::Geometry& triangle = surfaces_.geometry(index);
        double t, u, w;
        if (SegmentTriangle(q, dir, dir_length, triangle.corner[0], triangle.edge[0],
                            triangle.edge[1], triangle.edge_lengths, t, u, w)) {
          consider(index, t, u, w);
        }
      };
      if (small) {
        // a small object's triangles are all in its list, none in the
        // grid: tested four at a time, box and crossing
        const int num_faces = surfaces_.entry_end(b) - entry_begin;
        const Surfaces::SmallGroup* groups = surfaces_.groups(b);
        const Box4 segment_box(segment_lo, segment_hi);
        for (int g = 0; g < (num_faces + 3) / 4; ++g) {
          const Surfaces::SmallGroup& group = groups[g];
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
        const Surfaces::Table& hashed = surfaces_.table(b);
        if (hashed.large_tree.num_items() > 0) [[unlikely]] {
          hashed.large_tree.Overlapping(segment_lo, segment_hi,
                                        [&](int item) { test_triangle(hashed.large[item]); });
        } else {
          for (int index : hashed.large) {
            const Surfaces::Entry& entry = surfaces_.entry(index);
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
          const Surfaces::SmallGroup& group = surfaces_.groups(b)[f / 4];
          const int lane = f % 4;
          return Lane(group.edge0, lane).cross(Lane(group.edge1, lane));
        }
        const Surfaces::Geometry& triangle = surfaces_.geometry(best_entry);
        return triangle.edge[0].cross(triangle.edge[1]);
      };
      if (!SmoothNormal(surfaces_.normals(b).row(surface_b(f, 0)).transpose(),
                        surfaces_.normals(b).row(surface_b(f, 1)).transpose(),
                        surfaces_.normals(b).row(surface_b(f, 2)).transpose(), best_u, best_v,
                        face_normal, normal)) {
        continue;
      }
      sums.Add(crossing - p, normal);
    }
    if (!sums.any()) {  // not a border point (or no crossing found)
      candidates.resize(num_listed);
      return;
    }
    sums.Result(depth_[h], direction_[h]);
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
            emit(surfaces_.builder(colliding_.hits()[h].penetrated) % threads, h);
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

}  // namespace tetcosim
