#pragma once

// Tetrahedral meshes: the raw data a reader or generator produces, and the
// validated, immutable TetMesh with the derived data that collision and
// deformable both need (surface, edges, adjacency, normals, rest volumes).
//
// Conventions: lengths in metres (or whatever unit the file uses; tetcosim
// never rescales silently), positions in the mesh's own frame. A tetrahedron
// (a, b, c, d) has positive orientation when (b-a) x (c-a) . (d-a) > 0.

#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <vector>

namespace tetcosim {

// #V x 3 positions, one row per vertex (row-major, so that the rows of the
// whole matrix are one contiguous 3V vector of x0 y0 z0 x1 y1 z1 ...).
using Positions = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>;
// #T x 4 vertex indices, one row per tetrahedron.
using Tets = Eigen::Matrix<int, Eigen::Dynamic, 4, Eigen::RowMajor>;
// #F x 3 vertex indices, one row per triangle.
using Triangles = Eigen::Matrix<int, Eigen::Dynamic, 3, Eigen::RowMajor>;
// #E x 2 vertex indices, one row per edge, first index < second.
using Edges = Eigen::Matrix<int, Eigen::Dynamic, 2, Eigen::RowMajor>;

// What a reader or generator hands over before validation. The optional
// fields carry the file's own numbering so that errors can name the element
// and line the user sees in the file.
struct RawMesh {
  Positions positions;                // #V x 3
  Tets tets;                          // #T x 4, indices into positions
  std::vector<int> tet_tags;          // #T physical tags (empty if none)
  std::vector<long> node_ids;         // #V ids as in the file (empty: index)
  std::vector<long> element_ids;      // #T ids as in the file (empty: index)
  std::vector<long> element_lines;    // #T line in the file (empty: unknown)
  std::vector<long> node_lines;       // #V line in the file (empty: unknown)
  std::string source;                 // file name or generator spec, for messages
  std::vector<std::string> warnings;  // the reader's, passed on to TetMesh::warnings()
};

struct TetMeshOptions {
  // Inverted tetrahedra (negative volume) are flipped (two vertices swapped)
  // and reported as a warning when true; rejected with an error when false.
  bool flip_inverted = true;
  // A tetrahedron is degenerate when 6*sqrt(2)*V / l_rms^3 (1 for a regular
  // tetrahedron, 0 for a flat one) is below this.
  double min_shape_quality = 1e-6;
  // Vertices that no tetrahedron uses are dropped (with a warning) when true.
  bool drop_unreferenced = true;
};

// A validated tetrahedral mesh with derived data, computed once. Immutable:
// simulation state (current positions, velocities) lives elsewhere and refers
// to a TetMesh for topology and rest data.
class TetMesh {
 public:
  // Validates raw and computes the derived data. Throws Error naming the
  // source, line and element for: no tetrahedra, non-finite coordinates,
  // index out of range, repeated vertex in a tetrahedron, degenerate or (with
  // flip_inverted = false) inverted tetrahedra, duplicate tetrahedra, faces
  // shared by more than two tetrahedra, non-manifold boundary edges or
  // vertices, more than kMaxTets tetrahedra or kMaxVertices vertices.
  static TetMesh Build(RawMesh raw, const TetMeshOptions& options = {});

  // The most tetrahedra and vertices a mesh may have. Indices are int, and
  // every count made from them then fits in one too: the largest, the
  // entries of a deformable body's matrix, at most 9 (#V + 12 #T).
  static constexpr int kMaxTets = 10'000'000;
  static constexpr int kMaxVertices = 10'000'000;

  const std::string& source() const { return source_; }
  int num_vertices() const { return static_cast<int>(positions_.rows()); }
  int num_tets() const { return static_cast<int>(tets_.rows()); }

  const Positions& positions() const { return positions_; }       // #V x 3
  const Tets& tets() const { return tets_; }                      // #T x 4, positive volume
  const std::vector<int>& tet_tags() const { return tet_tags_; }  // #T or empty
  // File ids of the kept vertices (#V), or empty when the mesh is generated.
  const std::vector<long>& node_ids() const { return node_ids_; }

  // Boundary triangles (#F x 3), counter-clockwise seen from outside, so
  // that (b-a) x (c-a) points out of the body.
  const Triangles& surface() const { return surface_; }
  // For each surface triangle, the tetrahedron it belongs to (#F).
  const std::vector<int>& surface_tet() const { return surface_tet_; }
  // Vertices on the boundary, ascending (#S).
  const std::vector<int>& surface_vertices() const { return surface_vertices_; }
  bool is_surface_vertex(int v) const { return is_surface_vertex_[v] != 0; }

  const Edges& edges() const { return edges_; }  // #E x 2, unique, a < b

  // Vertex adjacency along edges in compressed rows: the neighbours of v are
  // adjacency()[adjacency_offsets()[v] .. adjacency_offsets()[v+1]), ascending.
  const std::vector<int>& adjacency_offsets() const { return adjacency_offsets_; }  // #V+1
  const std::vector<int>& adjacency() const { return adjacency_; }                  // 2#E
  // The most neighbours a vertex has (0 without edges).
  int max_degree() const { return max_degree_; }
  // Tetrahedra incident to each vertex, same compressed layout.
  const std::vector<int>& vertex_tet_offsets() const { return vertex_tet_offsets_; }  // #V+1
  const std::vector<int>& vertex_tets() const { return vertex_tets_; }                // 4#T
  // Surface triangles incident to each vertex, same layout, ascending
  // (empty for interior vertices).
  const std::vector<int>& vertex_triangle_offsets() const {
    return vertex_triangle_offsets_;
  }                                                                               // #V+1
  const std::vector<int>& vertex_triangles() const { return vertex_triangles_; }  // 3#F

  // A permutation of 0..#T-1 in which runs of kSpatialRun consecutive
  // tetrahedra lie close together at rest: the file's order if it already
  // is so (a generator's, cell by cell), else a Z-order (Morton) curve
  // through the rest centroids (a mesher's output is in no spatial order).
  // The collision solver takes tetrahedra in this order, kSpatialRun at a
  // time.
  static constexpr int kSpatialRun = 16;
  const std::vector<int>& spatial_tet_order() const { return spatial_tet_order_; }  // #T
  // The runs of spatial_tet_order: max(1, #T / kSpatialRun) of them, run r
  // at positions kSpatialRun r to kSpatialRun (r + 1) - 1, the last one to
  // the end; and the vertices of each run's tetrahedra, each once,
  // spatial_run_vertices()[spatial_run_vertex_offsets()[r] ..
  // spatial_run_vertex_offsets()[r + 1]). (The collision solver passes over
  // a run whose vertices all lie beyond one side of a box without reading
  // its tetrahedra: a body far larger than what touches it.)
  int num_spatial_runs() const { return static_cast<int>(spatial_run_vertex_offsets_.size()) - 1; }
  const std::vector<int>& spatial_run_vertex_offsets() const { return spatial_run_vertex_offsets_; }
  const std::vector<int>& spatial_run_vertices() const { return spatial_run_vertices_; }

  // Unit outward normals of surface vertices (area-weighted average of the
  // incident surface triangles' normals); zero rows for interior vertices.
  const Positions& vertex_normals() const { return vertex_normals_; }  // #V x 3
  // Rest volume of each tetrahedron (#T), > 0.
  const Eigen::VectorXd& rest_volumes() const { return rest_volumes_; }
  double total_volume() const { return total_volume_; }
  double average_edge_length() const { return average_edge_length_; }
  Eigen::Vector3d bbox_min() const { return bbox_min_; }
  Eigen::Vector3d bbox_max() const { return bbox_max_; }
  int num_flipped() const { return num_flipped_; }
  // Things the user should know that are not errors (flipped tetrahedra,
  // dropped vertices), one sentence each.
  const std::vector<std::string>& warnings() const { return warnings_; }

 private:
  TetMesh() = default;

  std::string source_;
  Positions positions_;
  Tets tets_;
  std::vector<int> tet_tags_;
  std::vector<long> node_ids_;
  Triangles surface_;
  std::vector<int> surface_tet_;
  std::vector<int> surface_vertices_;
  std::vector<std::uint8_t> is_surface_vertex_;
  Edges edges_;
  std::vector<int> adjacency_offsets_;
  std::vector<int> adjacency_;
  int max_degree_ = 0;
  std::vector<int> vertex_tet_offsets_;
  std::vector<int> vertex_tets_;
  std::vector<int> vertex_triangle_offsets_;
  std::vector<int> vertex_triangles_;
  std::vector<int> spatial_tet_order_;
  std::vector<int> spatial_run_vertex_offsets_;
  std::vector<int> spatial_run_vertices_;
  Positions vertex_normals_;
  Eigen::VectorXd rest_volumes_;
  double total_volume_ = 0.0;
  double average_edge_length_ = 0.0;
  Eigen::Vector3d bbox_min_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d bbox_max_ = Eigen::Vector3d::Zero();
  int num_flipped_ = 0;
  std::vector<std::string> warnings_;
};

// Signed volume of the tetrahedron (a, b, c, d): (b-a) x (c-a) . (d-a) / 6.
double SignedTetVolume(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& c,
                       const Eigen::Vector3d& d);

// Area-weighted unit vertex normals of a closed surface (#V x 3; zero rows
// for vertices on no triangle). Used at rest by TetMesh and every step by the
// collision solver for deformed bodies.
void ComputeVertexNormals(const Positions& positions, const Triangles& surface, Positions& normals);

// Row v of ComputeVertexNormals(positions, mesh.surface(), ...), bit for bit
// (the incident triangles summed in the same, ascending, order), from v's
// own triangles only: for callers that need a few vertices' normals.
Eigen::Vector3d VertexNormal(const TetMesh& mesh, const Positions& positions, int v);

}  // namespace tetcosim
