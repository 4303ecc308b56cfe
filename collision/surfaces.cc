// The penetration solver's surfaces: the triangles of the penetrated objects
// that stage 2 and closest features test, in per-object triangle hashes,
// lists and box trees, and their current vertex normals.

#include "collision/penetration.h"

#include <omp.h>

#include <algorithm>
#include <cstdint>
#include <limits>
#include <numeric>

#include "collision/penetration_internal.h"
#include "collision/simd4.h"
#include "mesh/parallel_for.h"

namespace tetcosim {
namespace {

// Triangles whose bounding box covers more cells than this are not hashed but
// tested against every query (large faces of coarse rigid proxies).
constexpr long kMaxTriangleCells = 64;

// Objects with at most this many surface triangles (the paper's 20-tet
// spheres) are not hashed: a query tests their few triangles directly,
// which is cheaper than walking the cells of a segment or a box tree.
constexpr int kSmallSurface = 48;

// Stage 2 finds the triangles too large to hash that a segment meets
// through a box tree when an object has more than this many, else by
// testing each (a coarse floor mesh under fine bodies has thousands).
constexpr int kMaxLargeListed = 16;

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

}  // namespace

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

}  // namespace tetcosim
