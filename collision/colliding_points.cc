// Stage 1 of the penetration solver: the colliding points, every vertex
// inside a tetrahedron of another object (or of its own, with
// self-collision), through the spatial hash of the vertices
// (CollidingPoints), and the solver's stage 1 overlapped with the surfaces.

#include "collision/colliding_points.h"

#include <omp.h>

#include <algorithm>
#include <atomic>
#include <bit>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <limits>
#include <thread>

#include "collision/geometry.h"
#include "collision/penetration.h"
#include "collision/penetration_internal.h"
#include "collision/simd4.h"
#include "mesh/parallel_for.h"

namespace tetcosim {
namespace {

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

// a chunk whose union of boxes covers more cells than this looks up its
// tets one by one (SearchChunk)
constexpr long kMaxChunkCells = 64;

// stage 1's vertex pass classifies the vertices in blocks of this many
constexpr int kVertexBlock = 1024;

// Objects with more partners than this look up all vertices near a
// tetrahedron at once instead of partner by partner (stage 1).
constexpr int kMaxKeyedPartners = 4;

// Stage 1's hits are sorted by comparison, not counted vertex by vertex,
// when there are more than this many vertices per hit.
constexpr int kMinVerticesPerCountedHit = 32;

// Whether stage 1 tests the vertices of object a against the tetrahedra of
// object b (a vertex in b's search box may be of any object): the broad
// phase's rule (MayCollide)
bool MayPenetrate(std::span<const CollisionObject> objects, int a, int b) {
  return MayCollide(objects[a], objects[b], a == b);
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

}  // namespace

void CollidingPoints::Begin(std::span<const CollisionObject> objects,
                            const GlobalVertices& vertices, std::span<KeptObject> kept,
                            bool any_kept, const BroadPhase& broad_phase, double cell_size) {
  objects_ = objects;
  vertices_ = &vertices;
  kept_ = kept;
  any_kept_ = any_kept;
  broad_phase_ = &broad_phase;
  cell_size_ = cell_size;
  inverse_cell_size_ = 1.0 / cell_size;  // (as SpatialHash::Reset computes it)
  const int num_objects = static_cast<int>(objects.size());
  // the chunks of tets, object after object: the runs of each object's
  // spatial order (TetMesh::num_spatial_runs)
  chunk_offset_.resize(num_objects + 1);
  chunk_offset_[0] = 0;
  for (int o = 0; o < num_objects; ++o) {
    chunk_offset_[o + 1] = chunk_offset_[o] + objects[o].mesh->num_spatial_runs();
  }
  if (!any_kept_) return;
  // a kept object's chunks to search: those whose box meets its search
  // box, found in its tree. (A fixed object's: exactly those that have a
  // vertex in the search box, as a chunk's vertices all lie beyond one side
  // of the search box just when the chunk's box does not meet it; a framed
  // object's: a few more, its search box taken into the body frame and
  // grown.)
  search_chunks_.clear();
  for (int o = 0; o < num_objects; ++o) {
    KeptObject& kept_object = kept_[o];
    if (!kept_object.active) {
      for (int c = chunk_offset_[o]; c < chunk_offset_[o + 1]; ++c) search_chunks_.push_back(c);
      continue;
    }
    kept_object.searched.clear();
    Eigen::Vector3d lo = broad_phase.search_lo(o), hi = broad_phase.search_hi(o);
    if (kept_object.framed && (lo.array() <= hi.array()).all()) {
      // the search box in the body frame: the box around it there, grown
      // as the kept boxes are
      const Eigen::Vector3d centre = kept_object.ToBody(0.5 * (lo + hi));
      const Eigen::Vector3d half = kept_object.rotation.transpose().cwiseAbs() * (0.5 * (hi - lo)) +
                                   Eigen::Vector3d::Constant(kept_object.pad);
      lo = centre - half;
      hi = centre + half;
    }
    kept_object.runs.Overlapping(lo, hi, [&](int run) { kept_object.searched.push_back(run); });
    std::sort(kept_object.searched.begin(), kept_object.searched.end());
    for (int run : kept_object.searched) search_chunks_.push_back(chunk_offset_[o] + run);
  }
}

void CollidingPoints::Find(int num_threads, double& hash_seconds, double& inside_seconds) {
  Clock::time_point start = Clock::now();
  const int num_vertices = vertices_->offset.back();
  num_threads = std::max(1, num_threads);
  // pass 1: hash the vertices that lie where a partner object can reach
  BeginVertexHash();
  const int num_blocks = (num_vertices + kVertexBlock - 1) / kVertexBlock;
  ParallelFor(ThreadsFor(num_threads, num_blocks, 4), 0, num_blocks, [&](int block) {
    ClassifyVertices(block * kVertexBlock, std::min(num_vertices, (block + 1) * kVertexBlock));
  });
  ClassifyKeptVertices();
  BuildVertexHash(num_threads);
  hash_seconds += SecondsSince(start);

  start = Clock::now();
  const int num_chunks = BeginSearch(num_threads);
  const int num_searched = any_hashed() ? num_chunks : 0;
  ParallelFor(
      ThreadsFor(num_threads, num_searched, kMinChunksPerThread), 0, num_searched,
      [&](int i) { SearchChunk(i); }, Schedule::kDynamic, kChunksPerGrab);
  SearchLargeTets(num_threads);
  MergeHits();
  inside_seconds += SecondsSince(start);
}

void CollidingPoints::BeginVertexHash() {
  const int num_vertices = vertices_->offset.back();
  vertex_cell_.resize(num_vertices);
  vertex_outcode_.resize(num_vertices);
}

void CollidingPoints::ClassifyVertices(int begin, int end) {
  for (int g = begin; g < end;) {  // object by object
    const int o = vertices_->object[g];
    const int offset = vertices_->offset[o];
    const int stop = std::min(end, vertices_->offset[o + 1]);
    if (kept_[o].active) {  // (ClassifyKeptVertices)
      g = stop;
      continue;
    }
    const Positions& x = *vertices_->positions[o];
    const Eigen::Vector3d lo = broad_phase_->search_lo(o), hi = broad_phase_->search_hi(o);
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

void CollidingPoints::ClassifyKeptVertices() {
  if (!any_kept_) return;
  const int num_objects = static_cast<int>(kept_.size());
  for (int o = 0; o < num_objects; ++o) {
    KeptObject& kept = kept_[o];
    if (!kept.active) continue;
    const int offset = vertices_->offset[o];
    std::uint8_t* outcode = vertex_outcode_.data() + offset;
    Eigen::Vector3i* cell = vertex_cell_.data() + offset;
    // (all set once while the object stays kept and in its place among the
    // objects; then only those classified in the last solve are reset)
    if (kept.outcode_offset != offset) {
      std::fill(outcode, outcode + (vertices_->offset[o + 1] - offset), kBeyondEverySide);
      kept.outcode_offset = offset;
    } else {
      for (int v : kept.classified) outcode[v] = kBeyondEverySide;
    }
    kept.classified.clear();
    kept.hashed.clear();
    const Positions& x = *vertices_->positions[o];
    const Eigen::Vector3d lo = broad_phase_->search_lo(o), hi = broad_phase_->search_hi(o);
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

void CollidingPoints::BuildVertexHash(int num_threads) {
  const int num_objects = static_cast<int>(vertices_->offset.size()) - 1;
  const int num_vertices = vertices_->offset.back();
  // a tetrahedron of an object with few partners looks up each partner's
  // vertices in the buckets of (cell, partner + 1); one of an object with
  // many (a pile of small bodies) looks up all vertices at once, in the
  // buckets of (cell, 0), which would cost one lookup per cell and partner
  bool keyed = false, unkeyed = false;
  for (int o = 0; o < num_objects; ++o) {
    const int count = broad_phase_->num_partners(o);
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
    add_blocks(span, vertices_->offset[o]);
    vertex_blocks_.push_back({0, static_cast<int>(kept_[o].hashed.size()), o});
    span = vertices_->offset[o + 1];
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
      if (keyed) hash_.SetInsertion(i++, vertex_cell_[g], g, vertices_->object[g] + 1);
      if (unkeyed) hash_.SetInsertion(i++, vertex_cell_[g], g);
    };
    if (block.kept >= 0) {
      const int offset = vertices_->offset[block.kept];
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
    const Eigen::Vector3d p = vertices_->Position(g);
    hashed_.x[e] = p.x();
    hashed_.y[e] = p.y();
    hashed_.z[e] = p.z();
    hashed_.vertex[e] = g;
    hashed_.object[e] = vertices_->object[g];
  });
}

int CollidingPoints::BeginSearch(int num_threads) {
  const int num_objects = static_cast<int>(objects_.size());
  bool any_deformable = false;  // (only rigid objects: no pair to test)
  for (const CollisionObject& object : objects_) any_deformable |= !object.rigid;
  if (static_cast<int>(thread_scratch_.size()) < num_threads) thread_scratch_.resize(num_threads);
  // (every thread ready for any share of the chunks, penetration_internal.h:
  // room for all the last solve's hits and large tets, and for the most
  // candidates a thread gathered from one chunk)
  const std::span<ThreadScratch> scratch(thread_scratch_);
  ClearForAnyShare(scratch, &ThreadScratch::hits);
  ClearForAnyShare(scratch, &ThreadScratch::large_tets);
  std::size_t most_gathered = 0;
  for (const ThreadScratch& thread : scratch) {
    most_gathered = std::max(most_gathered, thread.gathered.vertex.size());
  }
  for (ThreadScratch& thread : scratch) {
    if (thread.gathered.vertex.size() < most_gathered) thread.gathered.Resize(most_gathered);
    thread.tet_tests = 0;
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
void CollidingPoints::SearchChunk(int searched) {
  const int gc = SearchedChunk(searched);
  ThreadScratch& scratch = thread_scratch_[omp_get_thread_num()];
  HashedVertices& gathered = scratch.gathered;
  const int b = static_cast<int>(std::upper_bound(chunk_offset_.begin(), chunk_offset_.end(), gc) -
                                 chunk_offset_.begin()) -
                1;
  const CollisionObject& object_b = objects_[b];
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
  const std::uint8_t* outcode = vertex_outcode_.data() + vertices_->offset[b];
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
  // (search and for_each_in_cells always inlined, as ForEachBucket: called
  // out of line, they read every captured variable through the closure;
  // g++ left them out of line once this file was split from the solver's,
  // 1.5% more instructions a solve on the cubes and 100k)
  auto search = [&](const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, int partner, int key,
                    auto&& object_of) __attribute__((always_inline)) {
    const Eigen::Vector3d region_lo = union_lo.cwiseMax(lo);
    const Eigen::Vector3d region_hi = union_hi.cwiseMin(hi);
    if ((region_lo.array() > region_hi.array()).any()) return;
    const Eigen::Vector3i cell_lo = Cell(region_lo);
    const Eigen::Vector3i cell_hi = Cell(region_hi);
    // visit(e) for every entry e in `box` and the buckets of its cells
    auto for_each_in_cells = [&](const Eigen::Vector3i& from, const Eigen::Vector3i& to,
                                 const Box4& box, auto&& visit) __attribute__((always_inline)) {
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
        gathered.Resize(2 * (num_gathered + kSimdPadding + 1));
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
  if (broad_phase_->num_partners(b) > kMaxKeyedPartners) {
    // all vertices in B's search box
    search(broad_phase_->search_lo(b), broad_phase_->search_hi(b), -1, 0, [&](int e) {
      return MayPenetrate(objects_, hashed_.object[e], b) ? hashed_.object[e] : -1;
    });
    return;
  }
  for (int i = broad_phase_->partner_begin(b); i < broad_phase_->partner_end(b); ++i) {
    // partner A's vertices inside B lie in the overlap of their boxes
    const BroadPhase::Partner& partner = broad_phase_->partner(i);
    const int a = partner.object;
    search(partner.lo, partner.hi, i, a + 1,
           [&](int e) { return hashed_.object[e] == a ? a : -1; });
  }
}

void CollidingPoints::TestVertexInTet(const TetMesh& mesh_b, int b, SearchedTet& tet, int e, int a,
                                      ThreadScratch& scratch) const {
  if (a == b) {  // self-collision: not the tet's own vertices
    const int v = hashed_.vertex[e] - vertices_->offset[a];
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
void CollidingPoints::SearchLargeTets(int num_threads) {
  large_tets_.clear();
  for (const ThreadScratch& scratch : thread_scratch_) {
    large_tets_.insert(large_tets_.end(), scratch.large_tets.begin(), scratch.large_tets.end());
  }
  const int num_large = static_cast<int>(large_tets_.size());
  if (num_large == 0) return;
  const bool coarse = num_large >= kMinCoarseLargeTets;
  if (coarse) BuildCoarseVertexHash(num_threads);
  const int num_entries = hash_.num_items();
  const int threads = ThreadsFor(num_threads, num_large, 4);
  if (static_cast<int>(thread_scratch_.size()) < threads) thread_scratch_.resize(threads);
  ParallelFor(
      threads, 0, num_large,
      [&](int n) {
        const LargeTet& large = large_tets_[n];
        const int b = large.object;
        const CollisionObject& object_b = objects_[b];
        const Positions& x = *object_b.positions;
        SearchedTet tet;  // (its corners; its box: large.lo, large.hi)
        tet.t = large.tet;
        tet.have_coordinates = false;
        const auto vertices = object_b.mesh->tets().row(large.tet);
        for (int k = 0; k < 4; ++k) tet.corner[k] = x.row(vertices[k]).transpose();
        const int a_only = large.partner >= 0 ? broad_phase_->partner(large.partner).object : -1;
        ThreadScratch& scratch = thread_scratch_[omp_get_thread_num()];
        auto visit = [&](int e) {
          const int a = hashed_.object[e];
          if (a_only >= 0 ? a == a_only : MayPenetrate(objects_, a, b)) {
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

void CollidingPoints::BuildCoarseVertexHash(int num_threads) {
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
void CollidingPoints::MergeHits() {
  const int num_vertices = vertices_->offset.back();
  // (the last solve's hits leave the index; all of it when the vertices
  // are others)
  if (static_cast<int>(hit_range_.size()) != num_vertices) {
    hit_range_.assign(num_vertices, {0, 0});
  } else {
    for (const Hit& hit : hits_) hit_range_[hit.vertex] = {0, 0};
  }
  int num_found = 0;
  tet_tests_ = 0;
  for (const ThreadScratch& scratch : thread_scratch_) {
    num_found += static_cast<int>(scratch.hits.size());
    tet_tests_ += scratch.tet_tests;
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
  const int num_vertices = vertices_.offset.back();
  surface_list_ = broad_phase_.partnered();
  const int num_surfaces = static_cast<int>(surface_list_.size());
  colliding_.BeginVertexHash();
  colliding_.ClassifyKeptVertices();  // (before the surfaces, which read the outcodes)
  surfaces_.Place(objects, surface_list_, kept_, /*full=*/false, /*hash_and_normals=*/true,
                  cell_size_);
  const int num_chunks = colliding_.BeginSearch(threads);
  if (static_cast<int>(thread_scratch_.size()) < threads) thread_scratch_.resize(threads);
  // (any thread may make the largest surface: penetration_internal.h)
  ReserveLikeLargest(std::span<ThreadScratch>(thread_scratch_), &ThreadScratch::faces);
  std::atomic<bool> hash_built = false;
  std::atomic<int> surfaces_left = num_surfaces;
  Clock::time_point hash_end = start, surfaces_end = start;
#pragma omp parallel num_threads(threads)
  {
    // (an even share each; the loop's closing barrier is needed: the
    // surfaces read the outcodes)
#pragma omp for schedule(static)
    for (int part = 0; part < threads; ++part) {
      colliding_.ClassifyVertices(
          static_cast<int>(static_cast<long>(num_vertices) * part / threads),
          static_cast<int>(static_cast<long>(num_vertices) * (part + 1) / threads));
    }
#pragma omp single nowait
    {
      colliding_.BuildVertexHash(/*num_threads=*/1);  // (the other threads make surfaces meanwhile)
      hash_end = Clock::now();
      hash_built.store(true, std::memory_order_release);
    }
#pragma omp for schedule(dynamic, 1) nowait
    for (int i = 0; i < num_surfaces; ++i) {
      MakeSurface(objects, surface_list_[i]);
      if (surfaces_left.fetch_sub(1, std::memory_order_acq_rel) == 1) surfaces_end = Clock::now();
    }
    while (!hash_built.load(std::memory_order_acquire)) std::this_thread::yield();
    const int num_searched = colliding_.any_hashed() ? num_chunks : 0;
#pragma omp for schedule(dynamic, kChunksPerGrab) nowait
    for (int i = 0; i < num_searched; ++i) colliding_.SearchChunk(i);
  }
  colliding_.SearchLargeTets(options_.num_threads);
  colliding_.MergeHits();
  // the stages overlap: the wall time is split where the hash was built
  // and where the last surface was made
  const Clock::time_point surfaces_from = std::max(hash_end, surfaces_end);
  timings_.hash += std::chrono::duration<double>(hash_end - start).count();
  timings_.surfaces += std::chrono::duration<double>(surfaces_from - hash_end).count();
  timings_.inside += SecondsSince(surfaces_from);
}

}  // namespace tetcosim
