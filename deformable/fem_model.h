#pragma once

// Rest data of a deformable body, built once and shared by every body that
// uses the same mesh and material: shape-function gradients, volumes, lumped
// masses, contact areas, and the sparsity pattern of the implicit system.

#include <Eigen/Core>
#include <array>
#include <memory>
#include <vector>

#include "deformable/material.h"
#include "mesh/tet_mesh.h"

namespace tetcosim {

// Up to four tetrahedra processed together, one per SIMD lane
// (corotational.h's Lanes); unused lanes hold -1.
struct ElementBatch {
  std::array<int, 4> tets{-1, -1, -1, -1};
};

// The area each vertex stands for in contact (#V, m^2): a third of the
// incident surface triangles' area for surface vertices, (volume share)^(2/3)
// for interior ones.
Eigen::VectorXd ComputeContactAreas(const TetMesh& mesh);

// The surface area per surface vertex (m^2), from the mesh's contact areas
// (ComputeContactAreas): how finely the surface samples contact. A vertex
// of another mesh pressing into this one stands for at most this much area
// (see World's contacts).
double MeanSurfaceVertexArea(const TetMesh& mesh, const Eigen::VectorXd& contact_areas);

// What area a vertex stands for in a contact (<contact area>).
enum class ContactArea {
  kWhole,   // its share of the surface (ComputeContactAreas), as is
  kFacing,  // the part of that share that faces the contact (FacingContactArea)
};
const char* ContactAreaName(ContactArea area);  // as <contact area> spells it

// The part of a vertex's contact area (`area`, ComputeContactAreas) that
// faces the way the vertex is pushed, at `positions`: a third of each
// incident surface triangle's area times the cosine between its inward
// normal and `direction` (unit, the way out of what the vertex is in),
// where that is positive. A pressure p pushes a surface along `direction`
// with p times the area it shows that way, so that contact stiffnesses of
// kappa times this area press a flat contact to the depth p / kappa at
// every vertex, edges and corners too. With the whole share (kWhole), a
// block's edge and corner vertices count their side faces' area too (a
// block of 4 cells a side under a rigid plate: its top corners 0.074 mm
// deep, its middle 0.185 mm, where the pressure gives 0.194). At least
// kMinFacingShare of `area`, so that a vertex pushed along its own surface
// (a deep penetration's direction) still resists; an interior vertex
// stands for `area`.
inline constexpr double kMinFacingShare = 0.1;
double FacingContactArea(const TetMesh& mesh, const Positions& positions, int vertex,
                         const Eigen::Vector3d& direction, double area);
// `area` by `rule`: as is, or FacingContactArea.
double ContactAreaOf(ContactArea rule, const TetMesh& mesh, const Positions& positions, int vertex,
                     const Eigen::Vector3d& direction, double area);

class FemModel {
 public:
  // Throws Error if the material is invalid (`where` names the body).
  static std::shared_ptr<const FemModel> Build(std::shared_ptr<const TetMesh> mesh,
                                               const Material& material,
                                               const char* where = "body");

  const TetMesh& mesh() const { return *mesh_; }
  const std::shared_ptr<const TetMesh>& mesh_ptr() const { return mesh_; }
  const Material& material() const { return material_; }
  double mu() const { return mu_; }
  double lambda() const { return lambda_; }
  int num_vertices() const { return mesh_->num_vertices(); }
  int num_tets() const { return mesh_->num_tets(); }

  // Shape-function gradients b_0..b_3 of each tetrahedron (#T, 4 x 3, 1/m).
  const std::vector<Eigen::Matrix<double, 4, 3>>& gradients() const { return gradients_; }
  // Lumped vertex masses (#V, kg): a quarter of each incident tet's mass.
  const Eigen::VectorXd& masses() const { return masses_; }
  double total_mass() const { return total_mass_; }
  // Area each vertex stands for in contact (#V, m^2): a third of the incident
  // surface triangles' area for surface vertices, (volume share)^(2/3) for
  // interior ones.
  const Eigen::VectorXd& contact_areas() const { return contact_areas_; }
  // (total volume)^(1/3), metres: the body's size for default stiffnesses.
  double characteristic_length() const { return characteristic_length_; }

  // Sparsity of the 3V x 3V system in compressed rows: vertex v's rows
  // 3v..3v+2 hold the columns of v and its neighbours, three each, ascending.
  const std::vector<int>& row_start() const { return row_start_; }  // 3V + 1
  const std::vector<int>& columns() const { return columns_; }
  // For tet t and local vertices (a, b): where the columns of vertex b start
  // in the rows of vertex a, relative to each row's start.
  const std::vector<std::array<int, 16>>& element_slots() const { return element_slots_; }
  // Where the columns of vertex v start in its own rows.
  const std::vector<int>& diagonal_slot() const { return diagonal_slot_; }
  // The tetrahedra in batches of four: in mesh order (for one thread), and
  // colour by colour (a batch never spans two colours; batches
  // color_batch_offsets()[c] up to [c + 1] hold colour c). Colours come
  // from a greedy colouring in which no two tets of a colour share a vertex:
  // a colour's elements can be assembled in parallel, and the order of the
  // sums stays the same whatever the thread count.
  const std::vector<ElementBatch>& serial_batches() const { return serial_batches_; }
  const std::vector<ElementBatch>& colored_batches() const { return colored_batches_; }
  const std::vector<int>& color_batch_offsets() const { return color_batch_offsets_; }

 private:
  FemModel() = default;

  std::shared_ptr<const TetMesh> mesh_;
  Material material_;
  double mu_ = 0.0;
  double lambda_ = 0.0;
  std::vector<Eigen::Matrix<double, 4, 3>> gradients_;
  Eigen::VectorXd masses_;
  double total_mass_ = 0.0;
  Eigen::VectorXd contact_areas_;
  double characteristic_length_ = 0.0;
  std::vector<int> row_start_;
  std::vector<int> columns_;
  std::vector<std::array<int, 16>> element_slots_;
  std::vector<int> diagonal_slot_;
  std::vector<ElementBatch> serial_batches_;
  std::vector<ElementBatch> colored_batches_;
  std::vector<int> color_batch_offsets_;
};

}  // namespace tetcosim
