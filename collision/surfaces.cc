// The penetration solver's surfaces: the triangles of the penetrated objects
// that stage 2 and closest features test, in per-object triangle hashes,
// lists and box trees, and their current vertex normals (Surfaces), and the
// solver's stage that makes them.

#include "collision/surfaces.h"

#include <omp.h>

#include <algorithm>
#include <cstdint>
#include <limits>
#include <numeric>
#include <span>

#include "collision/penetration.h"
#include "collision/penetration_internal.h"
#include "collision/simd4.h"
#include "mesh/parallel_for.h"

namespace tetcosim {
namespace {

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

// Surface triangle f of a small object at its current position (x), as
// MakeTriangle computes it, into lane `lane` of a group.
void MakeSmallTriangle(const Positions& x, const Triangles& surface, int f,
                       Surfaces::SmallGroup& group, int lane) {
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

}  // namespace

// surface triangles of every penetrated object into the triangle hash (with
// full = false only those in the region a partner can reach: an
// intersection edge lies in the box of its own object), and current vertex
// normals of those objects
void PenetrationSolver::HashSurfaces(std::span<const CollisionObject> objects, bool full) {
  Clock::time_point start = Clock::now();
  const int num_objects = static_cast<int>(objects.size());
  object_penetrated_.assign(num_objects, 0);
  for (const Hit& hit : colliding_.hits()) object_penetrated_[hit.penetrated] = 1;
  surface_list_.clear();
  for (int o = 0; o < num_objects; ++o) {
    if (object_penetrated_[o]) surface_list_.push_back(o);
  }
  const int num_triangles =
      surfaces_.Place(objects, surface_list_, kept_, full,
                      /*hash_and_normals=*/options_.method == DepthMethod::kConsistent, cell_size_);
  const int threads = ThreadsFor(options_.num_threads, num_triangles, 128);
  if (static_cast<int>(thread_scratch_.size()) < threads) thread_scratch_.resize(threads);
  // (any thread may make the largest surface: penetration_internal.h)
  ReserveLikeLargest(std::span<ThreadScratch>(thread_scratch_), &ThreadScratch::faces);
  // consecutive objects to a thread: their entries (and small groups)
  // are neighbours, and two threads writing either side of a cache line
  // would pass it back and forth; a few grabs per thread still balance
  const int num_surfaces = static_cast<int>(surface_list_.size());
  const int objects_per_grab = std::max(1, num_surfaces / (4 * threads));
  ParallelFor(
      threads, 0, num_surfaces, [&](int i) { MakeSurface(objects, surface_list_[i]); },
      Schedule::kDynamic, objects_per_grab);
  timings_.surfaces += SecondsSince(start);
}

void PenetrationSolver::MakeSurface(std::span<const CollisionObject> objects, int o) {
  surfaces_.Make(objects, o, kept_[o], colliding_.outcodes(o),
                 thread_scratch_[omp_get_thread_num()].faces);
}

int Surfaces::Place(std::span<const CollisionObject> objects, std::span<const int> list,
                    std::span<const KeptObject> kept, bool full, bool hash_and_normals,
                    double cell_size) {
  const int num_objects = static_cast<int>(objects.size());
  cell_size_ = cell_size;
  inverse_cell_size_ = 1.0 / cell_size;  // (as SpatialHash::Reset computes it)
  hash_and_normals_ = hash_and_normals;
  fully_.assign(num_objects, 0);
  small_.assign(num_objects, 0);
  entry_begin_.assign(num_objects, 0);
  entry_end_.assign(num_objects, 0);
  rest_begin_.assign(num_objects, 0);
  small_begin_.assign(num_objects, 0);
  rest_end_.assign(num_objects, 0);
  // each object's entries get a range the size of its whole surface, so
  // that every object can be made at once, without first counting the
  // triangles in play
  int num_entries = 0, num_small = 0;
  for (int o : list) {
    const int num_faces = static_cast<int>(objects[o].mesh->surface().rows());
    small_[o] = num_faces <= kSmallSurface;
    // (a kept object's closest features come from the tree kept of it:
    // its faces in play, as for stage 2, are enough)
    fully_[o] = small_[o] || (full && !kept[o].active);
    entry_begin_[o] = num_entries;
    entry_end_[o] = num_entries;
    num_entries += num_faces;
    small_begin_[o] = num_small;
    if (small_[o]) num_small += (num_faces + 3) / 4;
  }
  entries_.resize(num_entries);
  geometry_.resize(num_entries);
  groups_.resize(num_small);
  if (++normal_round_ == 0) {  // wrapped: stamps would be ambiguous
    for (auto& stamps : normal_stamp_) std::fill(stamps.begin(), stamps.end(), 0);
    normal_round_ = 1;
  }
  normal_stamp_.resize(num_objects);
  normals_.resize(num_objects);
  tables_.resize(num_objects);
  builder_.resize(num_objects);
  return num_entries;
}

void Surfaces::Make(std::span<const CollisionObject> objects, int o, const KeptObject& kept,
                    const std::uint8_t* outcode, std::vector<int>& faces) {
  builder_[o] = omp_get_thread_num();
  const TetMesh& mesh = *objects[o].mesh;
  const Positions& x = *objects[o].positions;
  const int num_faces = static_cast<int>(mesh.surface().rows());
  int num_in_play = 0;
  if (fully_[o]) {
    faces.resize(num_faces);
    std::iota(faces.begin(), faces.end(), 0);
    num_in_play = num_faces;
  } else if (kept.active) {
    // among the faces of the searched chunks (a face in play meets the
    // search box, and so does the box of its tet's chunk), in order
    faces.clear();
    for (int run : kept.searched) {
      faces.insert(faces.end(), kept.run_faces.begin() + kept.run_face_offset[run],
                   kept.run_faces.begin() + kept.run_face_offset[run + 1]);
    }
    std::sort(faces.begin(), faces.end());
    const int* corner = mesh.surface().data();
    for (int i = 0; i < static_cast<int>(faces.size()); ++i) {
      faces[num_in_play] = faces[i];
      num_in_play += CornersInBox(outcode, corner + 3 * faces[i]);
    }
  } else {
    faces.resize(num_faces);
    // (TriangleInRegion's test, written for every face: branch-free)
    const int* corner = mesh.surface().data();
    for (int f = 0; f < num_faces; ++f) {
      faces[num_in_play] = f;
      num_in_play += CornersInBox(outcode, corner + 3 * f);
    }
  }
  faces.resize(num_in_play);
  entry_end_[o] = entry_begin_[o] + static_cast<int>(faces.size());
  long num_pairs = 0;  // (cell, triangle) pairs a hashed object's table will hold
  if (small_[o]) {     // every face, in order (fully hashed)
    SmallGroup* groups = &groups_[small_begin_[o]];
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
      const int index = entry_begin_[o] + n;
      Geometry& geometry = geometry_[index];
      MakeTriangle(objects, o, faces[n], entries_[index], geometry);
      const long cells = CellCount(geometry.cell_lo, geometry.cell_hi);
      if (cells <= kMaxTriangleCells) num_pairs += cells;
    }
  }
  // (closest features need neither the hash nor the normals: their queries
  // go through the object's box tree)
  if (!hash_and_normals_) return;
  if (!small_[o]) {  // (a small one is tested from the list)
    // a table twice the size of the (cell, triangle) pairs: few buckets
    // shared by cells, whose entries a query would test too
    tables_[o].hash.Reset(cell_size_, static_cast<int>(num_pairs));
    tables_[o].large.clear();
    for (int index = entry_begin_[o]; index < entry_end_[o]; ++index) {
      Insert(index);
    }
    BuildHash(o);
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

void Surfaces::AddRemaining(std::span<const CollisionObject> objects, int b, const KeptObject& kept,
                            const std::uint8_t* outcode) {
  if (fully_[b] || kept.active) return;  // (kept: its tree of all faces)
  fully_[b] = 1;
  const Triangles& surface = objects[b].mesh->surface();
  rest_begin_[b] = static_cast<int>(entries_.size());
  for (int f = 0; f < surface.rows(); ++f) {
    if (CornersInBox(outcode, &surface(f, 0))) continue;  // (in play: made)
    Entry entry;
    Geometry geometry;
    MakeTriangle(objects, b, f, entry, geometry);
    entries_.push_back(entry);
    geometry_.push_back(geometry);
  }
  rest_end_[b] = static_cast<int>(entries_.size());
}

void Surfaces::BuildTree(int b) {
  Table& hashed = tables_[b];
  hashed.tree_lo.clear();
  hashed.tree_hi.clear();
  hashed.tree_entry.clear();
  for (const auto& [begin, end] : {std::array<int, 2>{entry_begin_[b], entry_end_[b]},
                                   std::array<int, 2>{rest_begin_[b], rest_end_[b]}}) {
    for (int index = begin; index < end; ++index) {
      hashed.tree_lo.push_back(entries_[index].lo);
      hashed.tree_hi.push_back(entries_[index].hi);
      hashed.tree_entry.push_back(index);
    }
  }
  hashed.tree.Build(hashed.tree_lo, hashed.tree_hi);
}

void Surfaces::MakeTriangle(std::span<const CollisionObject> objects, int object, int f,
                            Entry& entry, Geometry& geometry) const {
  const Positions& x = *objects[object].positions;
  const Triangles& surface = objects[object].mesh->surface();
  for (int k = 0; k < 3; ++k) geometry.corner[k] = x.row(surface(f, k)).transpose();
  InflatedBounds(geometry.corner, entry.lo, entry.hi);
  entry.object = object;
  entry.face = f;
  geometry.edge[0] = geometry.corner[1] - geometry.corner[0];
  geometry.edge[1] = geometry.corner[2] - geometry.corner[0];
  geometry.edge_lengths = geometry.edge[0].norm() * geometry.edge[1].norm();
  geometry.cell_lo = GridCell(entry.lo, inverse_cell_size_);
  geometry.cell_hi = GridCell(entry.hi, inverse_cell_size_);
}

void Surfaces::Insert(int index) {
  const Geometry& geometry = geometry_[index];
  Table& hashed = tables_[entries_[index].object];
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

void Surfaces::BuildHash(int object) {
  Table& hashed = tables_[object];
  hashed.large_lo.clear();
  hashed.large_hi.clear();
  if (static_cast<int>(hashed.large.size()) > kMaxLargeListed) {
    for (int index : hashed.large) {
      hashed.large_lo.push_back(entries_[index].lo);
      hashed.large_hi.push_back(entries_[index].hi);
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
    const Entry& entry = entries_[items[e]];
    for (int k = 0; k < 3; ++k) {
      lo[k][e] = entry.lo[k];
      hi[k][e] = entry.hi[k];
    }
  }
}

}  // namespace tetcosim
