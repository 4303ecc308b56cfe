#include "mesh/tet_mesh.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <numeric>
#include <sstream>
#include <utility>

#include "mesh/error.h"
#include "mesh/group_by_key.h"

namespace tetcosim {
namespace {

// outward faces of a positively oriented tetrahedron (0, 1, 2, 3)
constexpr int kTetFaces[4][3] = {{1, 2, 3}, {0, 3, 2}, {0, 1, 3}, {0, 2, 1}};
constexpr int kTetEdges[6][2] = {{0, 1}, {0, 2}, {0, 3}, {1, 2}, {1, 3}, {2, 3}};

// describes tetrahedron t as the user knows it: "element 17 (line 40)"
std::string DescribeTet(const RawMesh& raw, int t) {
  std::ostringstream out;
  long id = raw.element_ids.empty() ? t : raw.element_ids[t];
  out << "element " << id;
  if (!raw.element_lines.empty() && raw.element_lines[t] > 0) {
    out << " (line " << raw.element_lines[t] << ")";
  }
  return out.str();
}

std::string DescribeNode(const RawMesh& raw, int v) {
  std::ostringstream out;
  long id = raw.node_ids.empty() ? v : raw.node_ids[v];
  out << "node " << id;
  if (!raw.node_lines.empty() && raw.node_lines[v] > 0) {
    out << " (line " << raw.node_lines[v] << ")";
  }
  return out.str();
}

[[noreturn]] void Fail(const RawMesh& raw, const std::string& message) {
  ThrowAt(raw.source, 0, message);
}

// sorted copy of a small index array, for topology keys
template <int N>
std::array<int, N> SortedKey(const int* v) {
  std::array<int, N> key;
  std::copy(v, v + N, key.begin());
  std::sort(key.begin(), key.end());
  return key;
}

// checks coordinates and indices; drops unreferenced vertices
void CheckAndCompact(RawMesh& raw, const TetMeshOptions& options,
                     std::vector<std::string>& warnings) {
  if (raw.tets.rows() > TetMesh::kMaxTets || raw.positions.rows() > TetMesh::kMaxVertices) {
    Fail(raw, "the mesh has " + std::to_string(raw.tets.rows()) + " tetrahedra and " +
                  std::to_string(raw.positions.rows()) + " vertices; tetcosim takes at most " +
                  std::to_string(TetMesh::kMaxTets) + " tetrahedra and " +
                  std::to_string(TetMesh::kMaxVertices) + " vertices in one mesh (its indices " +
                  "are 32-bit): mesh the body coarser or split it");
  }
  const int num_vertices = static_cast<int>(raw.positions.rows());
  const int num_tets = static_cast<int>(raw.tets.rows());
  if (num_tets == 0) {
    Fail(raw, "the mesh has no tetrahedra; tetcosim needs a volume mesh (in Gmsh: mesh with -3)");
  }
  for (int v = 0; v < num_vertices; ++v) {
    if (!raw.positions.row(v).allFinite()) {
      Fail(raw, DescribeNode(raw, v) + " has a non-finite coordinate (NaN or Inf); fix the file");
    }
  }
  std::vector<int> used(num_vertices, 0);
  for (int t = 0; t < num_tets; ++t) {
    for (int i = 0; i < 4; ++i) {
      int v = raw.tets(t, i);
      if (v < 0 || v >= num_vertices) {
        Fail(raw, DescribeTet(raw, t) + " refers to vertex " + std::to_string(v) +
                      ", outside the " + std::to_string(num_vertices) +
                      " vertices defined; check the node numbering");
      }
      used[v] = 1;
    }
    std::array<int, 4> key = SortedKey<4>(raw.tets.row(t).data());
    if (std::adjacent_find(key.begin(), key.end()) != key.end()) {
      Fail(raw, DescribeTet(raw, t) + " uses the same vertex twice");
    }
  }
  int num_used = std::accumulate(used.begin(), used.end(), 0);
  if (num_used == num_vertices || !options.drop_unreferenced) {
    if (num_used != num_vertices) {
      warnings.push_back(std::to_string(num_vertices - num_used) +
                         " vertices are used by no tetrahedron");
    }
    return;
  }
  // compact: new index of every used vertex
  std::vector<int> remap(num_vertices, -1);
  Positions kept(num_used, 3);
  std::vector<long> kept_ids;
  std::vector<long> kept_lines;
  int next = 0;
  for (int v = 0; v < num_vertices; ++v) {
    if (!used[v]) continue;
    remap[v] = next;
    kept.row(next) = raw.positions.row(v);
    kept_ids.push_back(raw.node_ids.empty() ? v : raw.node_ids[v]);
    if (!raw.node_lines.empty()) kept_lines.push_back(raw.node_lines[v]);
    ++next;
  }
  for (int t = 0; t < num_tets; ++t) {
    for (int i = 0; i < 4; ++i) raw.tets(t, i) = remap[raw.tets(t, i)];
  }
  warnings.push_back(std::to_string(num_vertices - num_used) +
                     " vertices are used by no tetrahedron and were dropped");
  raw.positions = std::move(kept);
  raw.node_ids = std::move(kept_ids);
  raw.node_lines = std::move(kept_lines);
}

// flips inverted tetrahedra, rejects degenerate ones; returns the number flipped
int OrientTets(RawMesh& raw, const TetMeshOptions& options) {
  int flipped = 0;
  for (int t = 0; t < raw.tets.rows(); ++t) {
    Eigen::Vector3d p[4];
    for (int i = 0; i < 4; ++i) p[i] = raw.positions.row(raw.tets(t, i)).transpose();
    double volume = SignedTetVolume(p[0], p[1], p[2], p[3]);
    double sum_sq = 0.0;
    for (const auto& e : kTetEdges) sum_sq += (p[e[0]] - p[e[1]]).squaredNorm();
    double l_rms = std::sqrt(sum_sq / 6.0);
    // 6 sqrt(2) V / l_rms^3: 1 for a regular tetrahedron, 0 for a flat one
    double quality = 6.0 * std::sqrt(2.0) * volume / (l_rms * l_rms * l_rms);
    if (!(std::abs(quality) >= options.min_shape_quality)) {
      std::ostringstream msg;
      msg << DescribeTet(raw, t) << " is degenerate (volume " << volume << ", shape quality "
          << std::abs(quality) << " below " << options.min_shape_quality
          << "); remesh or remove it";
      Fail(raw, msg.str());
    }
    if (volume < 0.0) {
      if (!options.flip_inverted) {
        Fail(raw, DescribeTet(raw, t) + " is inverted (negative volume)");
      }
      std::swap(raw.tets(t, 2), raw.tets(t, 3));
      ++flipped;
    }
  }
  return flipped;
}

void CheckDuplicates(const RawMesh& raw) {
  const int num_tets = static_cast<int>(raw.tets.rows());
  std::vector<std::pair<std::array<int, 4>, int>> keys(num_tets);
  for (int t = 0; t < num_tets; ++t) keys[t] = {SortedKey<4>(raw.tets.row(t).data()), t};
  std::sort(keys.begin(), keys.end());
  for (int i = 1; i < num_tets; ++i) {
    if (keys[i].first == keys[i - 1].first) {
      Fail(raw, DescribeTet(raw, keys[i].second) + " repeats " +
                    DescribeTet(raw, keys[i - 1].second) + " (same four vertices); remove one");
    }
  }
}

struct FaceRecord {
  std::array<int, 3> key;  // sorted vertex indices
  int tet;
  int local;  // which face of the tetrahedron
  bool operator<(const FaceRecord& o) const {
    return std::tie(key, tet, local) < std::tie(o.key, o.tet, o.local);
  }
};

// even permutation parity of an oriented triangle relative to its sorted key
bool SameCyclicOrder(const int* a, const std::array<int, 3>& key) {
  // rotate a so that its smallest comes first, then compare with key
  int s = static_cast<int>(std::min_element(a, a + 3) - a);
  return a[(s + 1) % 3] == key[1];
}

// The bits of v (below 2^21) spread to every third bit.
std::uint64_t SpreadBits(std::uint64_t v) {
  v &= 0x1fffff;
  v = (v | v << 32) & 0x1f00000000ffffull;
  v = (v | v << 16) & 0x1f0000ff0000ffull;
  v = (v | v << 8) & 0x100f00f00f00f00full;
  v = (v | v << 4) & 0x10c30c30c30c30c3ull;
  v = (v | v << 2) & 0x1249249249249249ull;
  return v;
}

// How compact runs of TetMesh::kSpatialRun consecutive tetrahedra are in
// `order`: the sum over runs of the volume of the bounding box of the run's
// tetrahedra grown by `margin` along each axis (a spatial hash of cell size
// `margin` looks up about that volume for the run).
constexpr int kSpatialRun = TetMesh::kSpatialRun;
double RunCost(const Positions& positions, const Tets& tets, const std::vector<int>& order,
               double margin) {
  double cost = 0.0;
  for (size_t begin = 0; begin < order.size(); begin += kSpatialRun) {
    const size_t end = std::min(order.size(), begin + kSpatialRun);
    Eigen::Vector3d lo = positions.row(tets(order[begin], 0)).transpose(), hi = lo;
    for (size_t i = begin; i < end; ++i) {
      for (int k = 0; k < 4; ++k) {
        lo = lo.cwiseMin(positions.row(tets(order[i], k)).transpose());
        hi = hi.cwiseMax(positions.row(tets(order[i], k)).transpose());
      }
    }
    cost += (hi - lo + Eigen::Vector3d::Constant(margin)).prod();
  }
  return cost;
}

// The file's order if its runs of tetrahedra are compact (a generator's,
// cell by cell), else the tetrahedra sorted by the Morton code of their
// centroids, quantised to 2^21 steps along the largest side of the box
// [lo, hi] (a mesher's output is in no spatial order); ties by index.
std::vector<int> SpatialOrder(const Positions& positions, const Tets& tets,
                              const Eigen::Vector3d& lo, const Eigen::Vector3d& hi,
                              double edge_length) {
  const int num_tets = static_cast<int>(tets.rows());
  Eigen::Matrix<double, Eigen::Dynamic, 3> centroids(num_tets, 3);
  for (int t = 0; t < num_tets; ++t) {
    centroids.row(t) = 0.25 * (positions.row(tets(t, 0)) + positions.row(tets(t, 1)) +
                               positions.row(tets(t, 2)) + positions.row(tets(t, 3)));
  }
  const double extent = (hi - lo).maxCoeff();
  const double scale = extent > 0.0 ? (double{1 << 21} - 1.0) / extent : 0.0;
  std::vector<std::pair<std::uint64_t, int>> keyed(num_tets);
  for (int t = 0; t < num_tets; ++t) {
    const Eigen::Vector3d q = ((centroids.row(t).transpose() - lo) * scale).cwiseMax(0.0);
    std::uint64_t code = 0;
    for (int k = 0; k < 3; ++k) code |= SpreadBits(static_cast<std::uint64_t>(q[k])) << k;
    keyed[t] = {code, t};
  }
  std::sort(keyed.begin(), keyed.end());
  std::vector<int> morton(num_tets), file(num_tets);
  for (int t = 0; t < num_tets; ++t) {
    morton[t] = keyed[t].second;
    file[t] = t;
  }
  return RunCost(positions, tets, file, edge_length) <=
                 RunCost(positions, tets, morton, edge_length)
             ? file
             : morton;
}

}  // namespace

double SignedTetVolume(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& c,
                       const Eigen::Vector3d& d) {
  return (b - a).cross(c - a).dot(d - a) / 6.0;
}

namespace {

// (b-a) x (c-a) of surface triangle f: |n| is twice the area, so summing
// these at a vertex weights its triangles by area for free
Eigen::RowVector3d AreaNormal(const Positions& positions, const Triangles& surface, int f) {
  Eigen::Vector3d a = positions.row(surface(f, 0));
  Eigen::Vector3d b = positions.row(surface(f, 1));
  Eigen::Vector3d c = positions.row(surface(f, 2));
  return (b - a).cross(c - a).transpose();
}

}  // namespace

void ComputeVertexNormals(const Positions& positions, const Triangles& surface,
                          Positions& normals) {
  normals.setZero(positions.rows(), 3);
  for (int f = 0; f < surface.rows(); ++f) {
    const Eigen::RowVector3d n = AreaNormal(positions, surface, f);
    for (int i = 0; i < 3; ++i) normals.row(surface(f, i)) += n;
  }
  for (int v = 0; v < normals.rows(); ++v) {
    double length = normals.row(v).norm();
    if (length > 0.0) normals.row(v) /= length;
  }
}

Eigen::Vector3d VertexNormal(const TetMesh& mesh, const Positions& positions, int v) {
  const Triangles& surface = mesh.surface();
  Eigen::RowVector3d normal = Eigen::RowVector3d::Zero();
  for (int k = mesh.vertex_triangle_offsets()[v]; k < mesh.vertex_triangle_offsets()[v + 1]; ++k) {
    normal += AreaNormal(positions, surface, mesh.vertex_triangles()[k]);
  }
  double length = normal.norm();
  if (length > 0.0) normal /= length;
  return normal.transpose();
}

TetMesh TetMesh::Build(RawMesh raw, const TetMeshOptions& options) {
  TetMesh mesh;
  mesh.warnings_ = std::move(raw.warnings);
  CheckAndCompact(raw, options, mesh.warnings_);
  mesh.num_flipped_ = OrientTets(raw, options);
  if (mesh.num_flipped_ > 0) {
    mesh.warnings_.push_back(std::to_string(mesh.num_flipped_) +
                             " tetrahedra had negative volume and were flipped");
  }
  CheckDuplicates(raw);

  const int num_vertices = static_cast<int>(raw.positions.rows());
  const int num_tets = static_cast<int>(raw.tets.rows());

  // faces: each appears once (boundary) or twice with opposite orientation
  std::vector<FaceRecord> faces;
  faces.reserve(4 * num_tets);
  for (int t = 0; t < num_tets; ++t) {
    for (int f = 0; f < 4; ++f) {
      int tri[3];
      for (int i = 0; i < 3; ++i) tri[i] = raw.tets(t, kTetFaces[f][i]);
      faces.push_back({SortedKey<3>(tri), t, f});
    }
  }
  std::sort(faces.begin(), faces.end());
  std::vector<std::array<int, 3>> boundary;
  std::vector<int> boundary_tet;
  for (size_t i = 0; i < faces.size();) {
    size_t j = i;
    while (j < faces.size() && faces[j].key == faces[i].key) ++j;
    const FaceRecord& first = faces[i];
    int tri[3];
    for (int k = 0; k < 3; ++k) tri[k] = raw.tets(first.tet, kTetFaces[first.local][k]);
    if (j - i == 1) {
      boundary.push_back({tri[0], tri[1], tri[2]});
      boundary_tet.push_back(first.tet);
    } else if (j - i == 2) {
      const FaceRecord& second = faces[i + 1];
      int other[3];
      for (int k = 0; k < 3; ++k) other[k] = raw.tets(second.tet, kTetFaces[second.local][k]);
      if (SameCyclicOrder(tri, first.key) == SameCyclicOrder(other, second.key)) {
        Fail(raw, DescribeTet(raw, first.tet) + " and " + DescribeTet(raw, second.tet) +
                      " overlap: they lie on the same side of their shared face");
      }
    } else {
      Fail(raw, "the face (" + std::to_string(first.key[0]) + ", " + std::to_string(first.key[1]) +
                    ", " + std::to_string(first.key[2]) + ") is shared by " +
                    std::to_string(j - i) + " tetrahedra, among them " +
                    DescribeTet(raw, faces[i].tet) + ", " + DescribeTet(raw, faces[i + 1].tet) +
                    " and " + DescribeTet(raw, faces[i + 2].tet) + "; the mesh is not manifold");
    }
    i = j;
  }

  // boundary edges: exactly two boundary triangles each
  std::vector<std::pair<std::array<int, 2>, int>> boundary_edges;
  for (size_t f = 0; f < boundary.size(); ++f) {
    for (int k = 0; k < 3; ++k) {
      int a = boundary[f][k];
      int b = boundary[f][(k + 1) % 3];
      boundary_edges.push_back({{std::min(a, b), std::max(a, b)}, static_cast<int>(f)});
    }
  }
  std::sort(boundary_edges.begin(), boundary_edges.end());
  for (size_t i = 0; i < boundary_edges.size();) {
    size_t j = i;
    while (j < boundary_edges.size() && boundary_edges[j].first == boundary_edges[i].first) ++j;
    if (j - i != 2) {
      auto [a, b] = boundary_edges[i].first;
      Fail(raw, "the boundary edge between " + DescribeNode(raw, a) + " and " +
                    DescribeNode(raw, b) + " belongs to " + std::to_string(j - i) +
                    " boundary triangles instead of 2; the boundary is not manifold "
                    "(tetrahedra touching along an edge)");
    }
    i = j;
  }

  // boundary vertices: the triangles around each form one fan
  {
    std::vector<std::vector<int>> vertex_faces(num_vertices);
    for (size_t f = 0; f < boundary.size(); ++f) {
      for (int v : boundary[f]) vertex_faces[v].push_back(static_cast<int>(f));
    }
    for (int v = 0; v < num_vertices; ++v) {
      const std::vector<int>& fan = vertex_faces[v];
      if (fan.empty()) continue;
      // walk from the first triangle across edges through v
      std::vector<char> seen(fan.size(), 0);
      std::vector<int> stack = {0};
      seen[0] = 1;
      size_t reached = 1;
      while (!stack.empty()) {
        int i = stack.back();
        stack.pop_back();
        for (size_t k = 0; k < fan.size(); ++k) {
          if (seen[k]) continue;
          // adjacent if the two triangles share an edge through v
          int shared = 0;
          for (int a : boundary[fan[i]]) {
            for (int b : boundary[fan[k]]) shared += (a == b);
          }
          if (shared >= 2) {
            seen[k] = 1;
            ++reached;
            stack.push_back(static_cast<int>(k));
          }
        }
      }
      if (reached != fan.size()) {
        Fail(raw, "the boundary is not manifold at " + DescribeNode(raw, v) +
                      ": parts of the mesh touch only at that vertex");
      }
    }
  }

  mesh.source_ = raw.source;
  mesh.positions_ = std::move(raw.positions);
  mesh.tets_ = std::move(raw.tets);
  mesh.tet_tags_ = std::move(raw.tet_tags);
  mesh.node_ids_ = std::move(raw.node_ids);

  mesh.surface_.resize(static_cast<Eigen::Index>(boundary.size()), 3);
  for (size_t f = 0; f < boundary.size(); ++f) {
    for (int k = 0; k < 3; ++k) mesh.surface_(static_cast<Eigen::Index>(f), k) = boundary[f][k];
  }
  mesh.surface_tet_ = std::move(boundary_tet);
  mesh.is_surface_vertex_.assign(num_vertices, 0);
  for (const auto& tri : boundary) {
    for (int v : tri) mesh.is_surface_vertex_[v] = 1;
  }
  for (int v = 0; v < num_vertices; ++v) {
    if (mesh.is_surface_vertex_[v]) mesh.surface_vertices_.push_back(v);
  }

  // unique edges
  std::vector<std::array<int, 2>> edges;
  edges.reserve(6 * num_tets);
  for (int t = 0; t < num_tets; ++t) {
    for (const auto& e : kTetEdges) {
      int a = mesh.tets_(t, e[0]);
      int b = mesh.tets_(t, e[1]);
      edges.push_back({std::min(a, b), std::max(a, b)});
    }
  }
  std::sort(edges.begin(), edges.end());
  edges.erase(std::unique(edges.begin(), edges.end()), edges.end());
  mesh.edges_.resize(static_cast<Eigen::Index>(edges.size()), 2);
  double edge_sum = 0.0;
  for (size_t e = 0; e < edges.size(); ++e) {
    mesh.edges_(static_cast<Eigen::Index>(e), 0) = edges[e][0];
    mesh.edges_(static_cast<Eigen::Index>(e), 1) = edges[e][1];
    edge_sum += (mesh.positions_.row(edges[e][0]) - mesh.positions_.row(edges[e][1])).norm();
  }
  mesh.average_edge_length_ = edge_sum / static_cast<double>(edges.size());

  // adjacency in compressed rows, each row sorted
  GroupByKey(
      num_vertices,
      [&](auto emit) {
        for (const auto& e : edges) {
          emit(e[0], e[1]);
          emit(e[1], e[0]);
        }
      },
      mesh.adjacency_offsets_, mesh.adjacency_);
  for (int v = 0; v < num_vertices; ++v) {
    std::sort(mesh.adjacency_.begin() + mesh.adjacency_offsets_[v],
              mesh.adjacency_.begin() + mesh.adjacency_offsets_[v + 1]);
    mesh.max_degree_ =
        std::max(mesh.max_degree_, mesh.adjacency_offsets_[v + 1] - mesh.adjacency_offsets_[v]);
  }
  // tetrahedra and surface triangles at each vertex, ascending
  GroupByKey(
      num_vertices,
      [&](auto emit) {
        for (int t = 0; t < num_tets; ++t) {
          for (int i = 0; i < 4; ++i) emit(mesh.tets_(t, i), t);
        }
      },
      mesh.vertex_tet_offsets_, mesh.vertex_tets_);
  GroupByKey(
      num_vertices,
      [&](auto emit) {
        for (int f = 0; f < mesh.surface_.rows(); ++f) {
          for (int i = 0; i < 3; ++i) emit(mesh.surface_(f, i), f);
        }
      },
      mesh.vertex_triangle_offsets_, mesh.vertex_triangles_);

  ComputeVertexNormals(mesh.positions_, mesh.surface_, mesh.vertex_normals_);
  mesh.rest_volumes_.resize(num_tets);
  for (int t = 0; t < num_tets; ++t) {
    mesh.rest_volumes_[t] = SignedTetVolume(mesh.positions_.row(mesh.tets_(t, 0)).transpose(),
                                            mesh.positions_.row(mesh.tets_(t, 1)).transpose(),
                                            mesh.positions_.row(mesh.tets_(t, 2)).transpose(),
                                            mesh.positions_.row(mesh.tets_(t, 3)).transpose());
  }
  mesh.total_volume_ = mesh.rest_volumes_.sum();
  mesh.bbox_min_ = mesh.positions_.colwise().minCoeff().transpose();
  mesh.bbox_max_ = mesh.positions_.colwise().maxCoeff().transpose();
  mesh.spatial_tet_order_ = SpatialOrder(mesh.positions_, mesh.tets_, mesh.bbox_min_,
                                         mesh.bbox_max_, mesh.average_edge_length_);
  const int num_runs = std::max(1, num_tets / kSpatialRun);
  mesh.spatial_run_vertex_offsets_.assign(1, 0);
  mesh.spatial_run_vertices_.clear();
  std::vector<int> run_vertices;
  for (int r = 0; r < num_runs; ++r) {
    const int end = r + 1 == num_runs ? num_tets : kSpatialRun * (r + 1);
    run_vertices.clear();
    for (int n = kSpatialRun * r; n < end; ++n) {
      for (int k = 0; k < 4; ++k) run_vertices.push_back(mesh.tets_(mesh.spatial_tet_order_[n], k));
    }
    std::sort(run_vertices.begin(), run_vertices.end());
    run_vertices.erase(std::unique(run_vertices.begin(), run_vertices.end()), run_vertices.end());
    mesh.spatial_run_vertices_.insert(mesh.spatial_run_vertices_.end(), run_vertices.begin(),
                                      run_vertices.end());
    mesh.spatial_run_vertex_offsets_.push_back(static_cast<int>(mesh.spatial_run_vertices_.size()));
  }
  return mesh;
}

}  // namespace tetcosim
