#include "collision/penetration.h"

#include <omp.h>

#include <algorithm>
#include <atomic>
#include <cassert>
#include <chrono>
#include <cmath>
#include <limits>

#include "collision/geometry.h"
#include "mesh/parallel_for.h"

namespace tetcosim {
namespace {

using Clock = std::chrono::steady_clock;

double SecondsSince(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

// Triangles whose bounding box covers more cells than this are not hashed but
// tested against every query (large faces of coarse rigid proxies).
constexpr long kMaxTriangleCells = 64;
// Tetrahedra whose bounding box covers more cells than this test candidate
// vertices directly instead of cell by cell.
constexpr long kMaxTetCells = 512;
// Objects with at most this many surface triangles (the paper's 20-tet
// spheres) are not hashed: a query tests their few triangles directly,
// which is cheaper than walking the cells of a segment or a search shell.
constexpr int kSmallSurface = 48;

long CellCount(const Eigen::Vector3i& lo, const Eigen::Vector3i& hi) {
  long count = 1;
  for (int a = 0; a < 3; ++a) count *= static_cast<long>(hi[a]) - lo[a] + 1;
  return count;
}

}  // namespace

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

PenetrationSolver::PenetrationSolver(PenetrationOptions options) : options_(options) {}

Eigen::Vector3d PenetrationSolver::Position(int global_vertex) const {
  int object = vertex_object_[global_vertex];
  return positions_[object]->row(global_vertex - vertex_offset_[object]).transpose();
}

int PenetrationSolver::FindHit(int vertex, int penetrated) const {
  for (int h = hit_offset_[vertex]; h < hit_offset_[vertex + 1]; ++h) {
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
  FindCollidingPoints(objects);
  HashSurfaces(objects, /*full=*/options_.method == DepthMethod::kClosest);
  if (options_.method == DepthMethod::kConsistent) {
    FindCrossings(objects);
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
    assert(object.mesh != nullptr && object.positions != nullptr);
    assert(object.positions->rows() == object.mesh->num_vertices());
    vertex_offset_[o + 1] = vertex_offset_[o] + object.mesh->num_vertices();
    positions_[o] = object.positions;
    edge_sum +=
        object.mesh->average_edge_length() * static_cast<double>(object.mesh->edges().rows());
    edge_count += object.mesh->edges().rows();
  }
  const int num_vertices = vertex_offset_[num_objects];
  vertex_object_.resize(num_vertices);
  for (int o = 0; o < num_objects; ++o) {
    std::fill(vertex_object_.begin() + vertex_offset_[o],
              vertex_object_.begin() + vertex_offset_[o + 1], o);
  }
  cell_size_ = options_.cell_size > 0.0 ? options_.cell_size
               : edge_count > 0         ? edge_sum / static_cast<double>(edge_count)
                                        : 1.0;
  // broad phase: bounding boxes, and the pairs of objects whose boxes overlap
  object_lo_.resize(num_objects);
  object_hi_.resize(num_objects);
  for (int o = 0; o < num_objects; ++o) {
    object_lo_[o] = objects[o].positions->colwise().minCoeff().transpose();
    object_hi_[o] = objects[o].positions->colwise().maxCoeff().transpose();
  }
  partner_offset_.resize(num_objects + 1);
  partner_offset_[0] = 0;
  partners_.clear();
  for (int b = 0; b < num_objects; ++b) {
    for (int a = 0; a < num_objects; ++a) {
      bool may_collide =
          a == b ? objects[b].self_collision : !(objects[a].rigid && objects[b].rigid);
      if (may_collide && (object_lo_[a].array() <= object_hi_[b].array()).all() &&
          (object_lo_[b].array() <= object_hi_[a].array()).all()) {
        partners_.push_back(a);
      }
    }
    partner_offset_[b + 1] = static_cast<int>(partners_.size());
  }
}

bool PenetrationSolver::OverlapsPartner(int b, const Eigen::Vector3d& lo,
                                        const Eigen::Vector3d& hi) const {
  for (int i = partner_offset_[b]; i < partner_offset_[b + 1]; ++i) {
    int a = partners_[i];
    if ((lo.array() <= object_hi_[a].array()).all() &&
        (object_lo_[a].array() <= hi.array()).all()) {
      return true;
    }
  }
  return false;
}

// stage 1: every vertex inside a tetrahedron of another object
void PenetrationSolver::FindCollidingPoints(std::span<const CollisionObject> objects) {
  Clock::time_point start = Clock::now();
  const int num_objects = static_cast<int>(objects.size());
  const int num_vertices = vertex_offset_[num_objects];
  const int num_threads = std::max(1, options_.num_threads);
  // hash only vertices that lie in the box of an object they may be inside
  vertex_cell_.resize(num_vertices);
  vertex_hashed_.resize(num_vertices);
  hash_.Reset(cell_size_, 0);  // sets the cell size for CellOf; sized below
  ParallelFor(num_threads, 0, num_vertices, [&](int g) {
    Eigen::Vector3d p = Position(g);
    vertex_hashed_[g] = OverlapsPartner(vertex_object_[g], p, p);
    if (vertex_hashed_[g]) vertex_cell_[g] = hash_.CellOf(p);
  });
  int num_hashed = 0;
  for (int g = 0; g < num_vertices; ++g) num_hashed += vertex_hashed_[g];
  hash_.Reset(cell_size_, num_hashed);
  for (int g = 0; g < num_vertices; ++g) {
    if (vertex_hashed_[g]) hash_.Insert(vertex_cell_[g], g);
  }
  timings_.hash += SecondsSince(start);

  start = Clock::now();
  bool any_deformable = false;
  for (const CollisionObject& object : objects) any_deformable |= !object.rigid;
  std::vector<int> tet_offset_storage;  // small: #objects + 1
  tet_offset_storage.reserve(num_objects + 1);
  tet_offset_storage.push_back(0);
  for (const CollisionObject& object : objects) {
    tet_offset_storage.push_back(tet_offset_storage.back() + object.mesh->num_tets());
  }
  const int num_tets = tet_offset_storage.back();
  if (static_cast<int>(thread_hits_.size()) < num_threads) thread_hits_.resize(num_threads);
  for (auto& buffer : thread_hits_) buffer.clear();

  // (no vertex in the box of a partner object: nothing can be inside)
  const int num_searched = any_deformable && num_hashed > 0 ? num_tets : 0;
  ParallelFor(
      num_threads, 0, num_searched,
      [&](int gt) {
        std::vector<Hit>& found = thread_hits_[omp_get_thread_num()];
        int b = static_cast<int>(
                    std::upper_bound(tet_offset_storage.begin(), tet_offset_storage.end(), gt) -
                    tet_offset_storage.begin()) -
                1;
        int t = gt - tet_offset_storage[b];
        const CollisionObject& object_b = objects[b];
        const Positions& x = *object_b.positions;
        const auto tet = object_b.mesh->tets().row(t);
        Eigen::Vector3d corner[4];
        for (int i = 0; i < 4; ++i) corner[i] = x.row(tet[i]).transpose();
        Eigen::Vector3d lo = corner[0].cwiseMin(corner[1]).cwiseMin(corner[2].cwiseMin(corner[3]));
        Eigen::Vector3d hi = corner[0].cwiseMax(corner[1]).cwiseMax(corner[2].cwiseMax(corner[3]));
        if (!OverlapsPartner(b, lo, hi)) return;  // broad phase: nothing can be inside
        auto test = [&](int g) {
          int a = vertex_object_[g];
          if (a == b) {
            if (!object_b.self_collision) return;
            int v = g - vertex_offset_[a];
            if (v == tet[0] || v == tet[1] || v == tet[2] || v == tet[3]) return;
          } else if (object_b.rigid && objects[a].rigid) {
            return;
          }
          Eigen::Vector3d p = Position(g);
          if ((p.array() < lo.array()).any() || (p.array() > hi.array()).any()) return;
          Eigen::Vector4d l;
          if (!TetBarycentric(corner[0], corner[1], corner[2], corner[3], p, l)) return;
          // (kBarycentricTolerance: a vertex on a face shared by two tets is
          // inside both in exact arithmetic, but rounding may put it just
          // outside each; the deepest tet is kept below)
          if (l.minCoeff() >= -kBarycentricTolerance) found.push_back({g, b, t, l});
        };
        Eigen::Vector3i cell_lo = hash_.CellOf(lo);
        Eigen::Vector3i cell_hi = hash_.CellOf(hi);
        if (CellCount(cell_lo, cell_hi) > kMaxTetCells) {
          for (int g = 0; g < num_vertices; ++g) {
            if (vertex_hashed_[g]) test(g);
          }
          return;
        }
        for (int k = cell_lo.z(); k <= cell_hi.z(); ++k) {
          for (int j = cell_lo.y(); j <= cell_hi.y(); ++j) {
            for (int i = cell_lo.x(); i <= cell_hi.x(); ++i) {
              Eigen::Vector3i cell(i, j, k);
              // a bucket holds vertices of every cell hashed to it: keep only
              // this cell's, which also visits each vertex once per tet
              hash_.ForEach(cell, [&](int g) {
                if (vertex_cell_[g] == cell) test(g);
              });
            }
          }
        }
      },
      Schedule::kDynamic, 256);
  // merge and sort: the order (and so the result) does not depend on threads
  hits_.clear();
  for (int i = 0; i < num_threads; ++i) {
    hits_.insert(hits_.end(), thread_hits_[i].begin(), thread_hits_[i].end());
  }
  std::sort(hits_.begin(), hits_.end());
  // one tetrahedron per (vertex, object): the one the vertex is deepest in
  // (a vertex on a shared face or edge is inside several)
  size_t kept = 0;
  for (size_t i = 0; i < hits_.size();) {
    size_t j = i;
    size_t best = i;
    while (j < hits_.size() && hits_[j].vertex == hits_[i].vertex &&
           hits_[j].penetrated == hits_[i].penetrated) {
      if (hits_[j].barycentric.minCoeff() > hits_[best].barycentric.minCoeff()) best = j;
      ++j;
    }
    hits_[kept++] = hits_[best];
    i = j;
  }
  hits_.resize(kept);
  hit_offset_.assign(num_vertices + 1, 0);
  for (const Hit& hit : hits_) ++hit_offset_[hit.vertex + 1];
  for (int g = 0; g < num_vertices; ++g) hit_offset_[g + 1] += hit_offset_[g];
  timings_.inside += SecondsSince(start);
}

// surface triangles of every penetrated object into the triangle hash (with
// full = false only those in the box of an object that may penetrate it: an
// intersection edge lies in the box of its own object), and current vertex
// normals of those objects
void PenetrationSolver::HashSurfaces(std::span<const CollisionObject> objects, bool full) {
  Clock::time_point start = Clock::now();
  const int num_objects = static_cast<int>(objects.size());
  object_penetrated_.assign(num_objects, 0);
  object_fully_hashed_.assign(num_objects, 0);
  for (const Hit& hit : hits_) object_penetrated_[hit.penetrated] = 1;
  int num_triangles = 0;
  for (int o = 0; o < num_objects; ++o) {
    if (object_penetrated_[o]) num_triangles += static_cast<int>(objects[o].mesh->surface().rows());
  }
  triangle_hash_.Reset(cell_size_, num_triangles);
  triangles_.clear();
  triangle_lo_.clear();
  triangle_hi_.clear();
  triangle_box_lo_.clear();
  triangle_box_hi_.clear();
  large_triangles_.clear();
  object_cell_lo_.resize(num_objects);
  object_cell_hi_.resize(num_objects);
  object_small_.assign(num_objects, 0);
  object_entry_begin_.assign(num_objects, 0);
  object_entry_end_.assign(num_objects, 0);
  for (int o = 0; o < num_objects; ++o) {
    if (!object_penetrated_[o]) continue;
    const Positions& x = *objects[o].positions;
    const Triangles& surface = objects[o].mesh->surface();
    ComputeVertexNormals(x, surface, normals_[o]);
    object_cell_lo_[o] = triangle_hash_.CellOf(object_lo_[o]);
    object_cell_hi_[o] = triangle_hash_.CellOf(object_hi_[o]);
    object_fully_hashed_[o] = full;
    object_small_[o] = surface.rows() <= kSmallSurface;
    object_entry_begin_[o] = static_cast<int>(triangles_.size());
    if (object_small_[o]) object_fully_hashed_[o] = 1;
    for (int f = 0; f < surface.rows(); ++f) {
      Eigen::Vector3d a = x.row(surface(f, 0)), b = x.row(surface(f, 1)), c = x.row(surface(f, 2));
      Eigen::Vector3d lo = a.cwiseMin(b).cwiseMin(c);
      Eigen::Vector3d hi = a.cwiseMax(b).cwiseMax(c);
      if (object_small_[o]) {
        InsertTriangle(o, f, lo, hi, /*grid=*/false);
      } else if (full || OverlapsPartner(o, lo, hi)) {
        InsertTriangle(o, f, lo, hi, /*grid=*/true);
      }
    }
    object_entry_end_[o] = static_cast<int>(triangles_.size());
  }
  timings_.hash += SecondsSince(start);
}

void PenetrationSolver::HashRemainingTriangles(std::span<const CollisionObject> objects, int b) {
  if (object_fully_hashed_[b]) return;
  object_fully_hashed_[b] = 1;
  const Positions& x = *objects[b].positions;
  const Triangles& surface = objects[b].mesh->surface();
  for (int f = 0; f < surface.rows(); ++f) {
    Eigen::Vector3d a = x.row(surface(f, 0)), c1 = x.row(surface(f, 1)), c2 = x.row(surface(f, 2));
    Eigen::Vector3d lo = a.cwiseMin(c1).cwiseMin(c2);
    Eigen::Vector3d hi = a.cwiseMax(c1).cwiseMax(c2);
    if (!OverlapsPartner(b, lo, hi)) InsertTriangle(b, f, lo, hi, /*grid=*/true);
  }
}

void PenetrationSolver::InsertTriangle(int object, int f, const Eigen::Vector3d& lo,
                                       const Eigen::Vector3d& hi, bool grid) {
  Eigen::Vector3i cell_lo = triangle_hash_.CellOf(lo);
  Eigen::Vector3i cell_hi = triangle_hash_.CellOf(hi);
  int entry = static_cast<int>(triangles_.size());
  triangles_.push_back({object, f});
  triangle_lo_.push_back(cell_lo);
  triangle_hi_.push_back(cell_hi);
  triangle_box_lo_.push_back(lo);
  triangle_box_hi_.push_back(hi);
  if (!grid) return;
  if (CellCount(cell_lo, cell_hi) > kMaxTriangleCells) {
    large_triangles_.push_back(entry);
    return;
  }
  for (int k = cell_lo.z(); k <= cell_hi.z(); ++k) {
    for (int j = cell_lo.y(); j <= cell_hi.y(); ++j) {
      for (int i = cell_lo.x(); i <= cell_hi.x(); ++i) {
        triangle_hash_.Insert({i, j, k}, entry, object + 1);
      }
    }
  }
}

// stage 2: for every colliding point p and neighbour q outside B, the
// crossing of the edge q -> p with B's surface nearest q
void PenetrationSolver::FindCrossings(std::span<const CollisionObject> objects) {
  Clock::time_point start = Clock::now();
  const int num_hits = static_cast<int>(hits_.size());
  crossing_offset_.resize(num_hits + 1);
  crossing_offset_[0] = 0;
  for (int h = 0; h < num_hits; ++h) {
    int g = hits_[h].vertex;
    int a = vertex_object_[g];
    int v = g - vertex_offset_[a];
    const auto& offsets = objects[a].mesh->adjacency_offsets();
    crossing_offset_[h + 1] = crossing_offset_[h] + offsets[v + 1] - offsets[v];
  }
  crossings_.resize(crossing_offset_[num_hits]);
  std::atomic<int> edges = 0;
  ParallelFor(
      std::max(1, options_.num_threads), 0, num_hits,
      [&](int h) {
        const Hit& hit = hits_[h];
        const int a = vertex_object_[hit.vertex];
        const int b = hit.penetrated;
        const int v = hit.vertex - vertex_offset_[a];
        const TetMesh& mesh_a = *objects[a].mesh;
        const Positions& x_b = *objects[b].positions;
        const Triangles& surface_b = objects[b].mesh->surface();
        const Eigen::Vector3d p = Position(hit.vertex);
        int slot = crossing_offset_[h];
        for (int n = mesh_a.adjacency_offsets()[v]; n < mesh_a.adjacency_offsets()[v + 1];
             ++n, ++slot) {
          Crossing& crossing = crossings_[slot];
          crossing.valid = false;
          const int q_local = mesh_a.adjacency()[n];
          const int q_global = vertex_offset_[a] + q_local;
          if (FindHit(q_global, b) >= 0) continue;  // q is inside B too: not an intersection edge
          ++edges;
          const Eigen::Vector3d q = Position(q_global);
          double best_t = std::numeric_limits<double>::infinity();
          int best_entry = -1;
          double best_u = 0.0, best_v = 0.0;
          const Eigen::Vector3d segment_lo = q.cwiseMin(p);
          const Eigen::Vector3d segment_hi = q.cwiseMax(p);
          auto test = [&](int entry) {
            if (triangles_[entry][0] != b) return;
            if ((triangle_box_lo_[entry].array() > segment_hi.array()).any() ||
                (segment_lo.array() > triangle_box_hi_[entry].array()).any()) {
              return;
            }
            const int f = triangles_[entry][1];
            if (a == b) {  // self-collision: the edge's own triangles do not count
              for (int k = 0; k < 3; ++k) {
                if (surface_b(f, k) == v || surface_b(f, k) == q_local) return;
              }
            }
            double t, u, w;
            if (!SegmentTriangle(q, p, x_b.row(surface_b(f, 0)), x_b.row(surface_b(f, 1)),
                                 x_b.row(surface_b(f, 2)), t, u, w)) {
              return;
            }
            // nearest to q; ties broken by entry for determinism
            if (t < best_t || (t == best_t && entry < best_entry)) {
              best_t = t;
              best_entry = entry;
              best_u = u;
              best_v = w;
            }
          };
          if (object_small_[b]) {
            // a small object's triangles are all in its list, none in the grid
            for (int entry = object_entry_begin_[b]; entry < object_entry_end_[b]; ++entry)
              test(entry);
          } else {
            for (int entry : large_triangles_) test(entry);
            Eigen::Vector3i lo = triangle_hash_.CellOf(segment_lo);
            Eigen::Vector3i hi = triangle_hash_.CellOf(segment_hi);
            for (int k = lo.z(); k <= hi.z(); ++k) {
              for (int j = lo.y(); j <= hi.y(); ++j) {
                for (int i = lo.x(); i <= hi.x(); ++i) {
                  Eigen::Vector3i cell(i, j, k);
                  triangle_hash_.ForEach(
                      cell,
                      [&](int entry) {
                        // test each triangle once: in the first cell the
                        // segment's and the triangle's cell ranges share
                        Eigen::Vector3i first = lo.cwiseMax(triangle_lo_[entry]);
                        if (cell == first && (cell.array() <= triangle_hi_[entry].array()).all()) {
                          test(entry);
                        }
                      },
                      b + 1);
                }
              }
            }
          }
          if (best_entry < 0) continue;
          const int f = triangles_[best_entry][1];
          crossing.point = q + best_t * (p - q);
          // smooth normal: barycentric interpolation of the vertex normals
          Eigen::Vector3d normal =
              (1.0 - best_u - best_v) * normals_[b].row(surface_b(f, 0)).transpose() +
              best_u * normals_[b].row(surface_b(f, 1)).transpose() +
              best_v * normals_[b].row(surface_b(f, 2)).transpose();
          double length = normal.norm();
          if (length < 1e-12) {  // opposite vertex normals cancel: use the face normal
            normal = (x_b.row(surface_b(f, 1)) - x_b.row(surface_b(f, 0)))
                         .cross(x_b.row(surface_b(f, 2)) - x_b.row(surface_b(f, 0)))
                         .transpose();
            length = normal.norm();
            if (length == 0.0) continue;
          }
          crossing.normal = normal / length;
          crossing.valid = true;
        }
      },
      Schedule::kDynamic, 64);
  stats_.intersection_edges = edges;
  timings_.intersect += SecondsSince(start);
}

// stage 3: depth and direction of border points from their crossings
void PenetrationSolver::ComputeBorderPoints(std::span<const CollisionObject> /*objects*/) {
  Clock::time_point start = Clock::now();
  const int num_hits = static_cast<int>(hits_.size());
  depth_.resize(num_hits);
  direction_.resize(num_hits);
  source_.resize(num_hits);
  layer_.assign(num_hits, -1);
  // a crossing closer than this to p means p is on the surface: depth 0
  const double on_surface = 1e-9 * cell_size_;
  ParallelFor(std::max(1, options_.num_threads), 0, num_hits, [&](int h) {
    const Eigen::Vector3d p = Position(hits_[h].vertex);
    double weight_sum = 0.0;
    double depth_sum = 0.0;
    Eigen::Vector3d normal_sum = Eigen::Vector3d::Zero();
    int nearest = -1;
    double nearest_distance = std::numeric_limits<double>::infinity();
    for (int s = crossing_offset_[h]; s < crossing_offset_[h + 1]; ++s) {
      const Crossing& crossing = crossings_[s];
      if (!crossing.valid) continue;
      Eigen::Vector3d to_crossing = crossing.point - p;
      double distance = to_crossing.norm();
      if (distance < nearest_distance) {
        nearest_distance = distance;
        nearest = s;
      }
      if (distance < on_surface) continue;
      // w_i = 1 / |x_i - p|^2 (method.md, stage 3)
      double w = 1.0 / (distance * distance);
      weight_sum += w;
      depth_sum += w * to_crossing.dot(crossing.normal);
      normal_sum += w * crossing.normal;
    }
    if (nearest < 0) return;  // not a border point (or no crossing found)
    if (nearest_distance < on_surface || weight_sum == 0.0) {
      depth_[h] = 0.0;
      direction_[h] = crossings_[nearest].normal;
    } else {
      depth_[h] = std::max(0.0, depth_sum / weight_sum);
      double length = normal_sum.norm();
      direction_[h] = length > 1e-12 * weight_sum ? Eigen::Vector3d(normal_sum / length)
                                                  : crossings_[nearest].normal;
    }
    source_[h] = DepthSource::kBorder;
    layer_[h] = 0;
  });
  timings_.border += SecondsSince(start);
}

// stage 4: propagation to inner points, each layer from earlier layers only
void PenetrationSolver::Propagate(std::span<const CollisionObject> objects) {
  Clock::time_point start = Clock::now();
  const int num_hits = static_cast<int>(hits_.size());
  constexpr int kInNextLayer = -2;
  frontier_.clear();
  for (int h = 0; h < num_hits; ++h) {
    if (layer_[h] == 0) frontier_.push_back(h);
  }
  const double coincident = 1e-9 * cell_size_;
  int layer = 0;
  while (!frontier_.empty()) {
    ++layer;
    next_frontier_.clear();
    for (int h : frontier_) {
      const int g = hits_[h].vertex;
      const int a = vertex_object_[g];
      const int v = g - vertex_offset_[a];
      const TetMesh& mesh = *objects[a].mesh;
      for (int n = mesh.adjacency_offsets()[v]; n < mesh.adjacency_offsets()[v + 1]; ++n) {
        int neighbour = FindHit(vertex_offset_[a] + mesh.adjacency()[n], hits_[h].penetrated);
        if (neighbour >= 0 && layer_[neighbour] == -1) {
          layer_[neighbour] = kInNextLayer;
          next_frontier_.push_back(neighbour);
        }
      }
    }
    std::sort(next_frontier_.begin(), next_frontier_.end());
    ParallelFor(
        std::max(1, options_.num_threads), 0, static_cast<int>(next_frontier_.size()), [&](int i) {
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
          for (int n = mesh.adjacency_offsets()[v]; n < mesh.adjacency_offsets()[v + 1]; ++n) {
            const int j_global = vertex_offset_[a] + mesh.adjacency()[n];
            const int j = FindHit(j_global, hits_[h].penetrated);
            if (j < 0 || layer_[j] < 0) continue;  // only points of earlier layers
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
          if (copy_from >= 0 || weight_sum == 0.0) {
            depth_[h] = depth_[copy_from];
            direction_[h] = direction_[copy_from];
          } else {
            depth_[h] = std::max(0.0, depth_sum / weight_sum);
            double length = direction_sum.norm();
            if (length > 1e-12 * weight_sum) {
              direction_[h] = direction_sum / length;
            } else {  // directions cancel: keep the nearest neighbour's
              direction_[h] = Eigen::Vector3d::Zero();
            }
          }
          source_[h] = DepthSource::kPropagated;
        });
    for (int h : next_frontier_) {
      layer_[h] = direction_[h].squaredNorm() > 0.0 ? layer : -1;
    }
    std::swap(frontier_, next_frontier_);
    // points whose neighbour directions cancelled stay unresolved; drop
    // them from the frontier
    frontier_.erase(
        std::remove_if(frontier_.begin(), frontier_.end(), [&](int h) { return layer_[h] < 0; }),
        frontier_.end());
  }
  stats_.layers = layer > 0 ? layer - 1 : 0;
  timings_.propagate += SecondsSince(start);
}

bool PenetrationSolver::ClosestSurfacePoint(std::span<const CollisionObject> objects, int b,
                                            const Eigen::Vector3d& p, int exclude,
                                            Eigen::Vector3d& closest) const {
  const Positions& x = *objects[b].positions;
  const Triangles& surface = objects[b].mesh->surface();
  double best = std::numeric_limits<double>::infinity();
  auto test = [&](int entry) {
    if (triangles_[entry][0] != b) return;
    const int f = triangles_[entry][1];
    if (exclude >= 0 &&
        (surface(f, 0) == exclude || surface(f, 1) == exclude || surface(f, 2) == exclude)) {
      return;
    }
    Eigen::Vector3d c =
        ClosestPointOnTriangle(p, x.row(surface(f, 0)), x.row(surface(f, 1)), x.row(surface(f, 2)));
    double d = (c - p).squaredNorm();
    if (d < best) {
      best = d;
      closest = c;
    }
  };
  if (object_small_[b]) {
    for (int entry = object_entry_begin_[b]; entry < object_entry_end_[b]; ++entry) test(entry);
    return std::isfinite(best);
  }
  for (int entry : large_triangles_) test(entry);
  // search cubes of cells of growing radius k around p's cell: every point
  // within k cells of p lies in the cube, so the search may stop as soon as
  // the best distance is at most k cell sizes
  const double cell_size = cell_size_;
  const Eigen::Vector3i center = triangle_hash_.CellOf(p);
  const Eigen::Vector3i& box_lo = object_cell_lo_[b];  // B's bounding box in cells
  const Eigen::Vector3i& box_hi = object_cell_hi_[b];
  for (int k = 0;; ++k) {
    Eigen::Vector3i lo = (center.array() - k).matrix().cwiseMax(box_lo);
    Eigen::Vector3i hi = (center.array() + k).matrix().cwiseMin(box_hi);
    for (int cz = lo.z(); cz <= hi.z(); ++cz) {
      for (int cy = lo.y(); cy <= hi.y(); ++cy) {
        for (int cx = lo.x(); cx <= hi.x(); ++cx) {
          Eigen::Vector3i cell(cx, cy, cz);
          // only the shell of the cube: the inside was searched before
          if ((cell - center).cwiseAbs().maxCoeff() != k) continue;
          // skip cells farther from p than the best so far
          Eigen::Vector3d cell_lo = cell.cast<double>() * cell_size_;
          Eigen::Vector3d gap = (cell_lo - p)
                                    .cwiseMax(p - cell_lo - Eigen::Vector3d::Constant(cell_size_))
                                    .cwiseMax(0.0);
          if (gap.squaredNorm() > best) continue;
          triangle_hash_.ForEach(
              cell,
              [&](int entry) {
                if ((cell.array() >= triangle_lo_[entry].array()).all() &&
                    (cell.array() <= triangle_hi_[entry].array()).all()) {
                  test(entry);
                }
              },
              b + 1);
        }
      }
    }
    if (best <= (k * cell_size) * (k * cell_size)) break;
    // the cube covers all of B's cells: nothing left to find
    if (((center.array() - k) <= box_lo.array()).all() &&
        ((center.array() + k) >= box_hi.array()).all()) {
      break;
    }
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
  for (int h = 0; h < num_hits; ++h) {
    if (layer_[h] < 0) HashRemainingTriangles(objects, hits_[h].penetrated);
  }
  ParallelFor(
      std::max(1, options_.num_threads), 0, num_hits,
      [&](int h) {
        if (layer_[h] >= 0) return;
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
          for (int i = 0; i < 4; ++i)
            centroid += objects[b].positions->row(tet[i]).transpose() / 4.0;
          Eigen::Vector3d out = p - centroid;
          direction_[h] =
              out.norm() > 0.0 ? Eigen::Vector3d(out.normalized()) : Eigen::Vector3d::UnitZ();
        }
        source_[h] = source;
        layer_[h] = std::numeric_limits<int>::max();
      },
      Schedule::kDynamic, 64);
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
