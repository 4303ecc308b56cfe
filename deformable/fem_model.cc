#include "deformable/fem_model.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdint>

#include "deformable/corotational.h"
#include "mesh/group_by_key.h"

namespace tetcosim {

Eigen::VectorXd ComputeContactAreas(const TetMesh& m) {
  Eigen::VectorXd areas = Eigen::VectorXd::Zero(m.num_vertices());
  Eigen::VectorXd volume_share = Eigen::VectorXd::Zero(m.num_vertices());
  for (int t = 0; t < m.num_tets(); ++t) {
    for (int i = 0; i < 4; ++i) volume_share[m.tets()(t, i)] += m.rest_volumes()[t] / 4.0;
  }
  for (Eigen::Index f = 0; f < m.surface().rows(); ++f) {
    Eigen::Vector3d a = m.positions().row(m.surface()(f, 0));
    Eigen::Vector3d b = m.positions().row(m.surface()(f, 1));
    Eigen::Vector3d c = m.positions().row(m.surface()(f, 2));
    double area = 0.5 * (b - a).cross(c - a).norm();
    for (int k = 0; k < 3; ++k) areas[m.surface()(f, k)] += area / 3.0;
  }
  for (int v = 0; v < m.num_vertices(); ++v) {
    if (!m.is_surface_vertex(v)) areas[v] = std::pow(volume_share[v], 2.0 / 3.0);
  }
  return areas;
}

double MeanSurfaceVertexArea(const TetMesh& m, const Eigen::VectorXd& contact_areas) {
  // (a surface vertex's contact area is a third of its triangles': they
  // add up to the surface's)
  double area = 0.0;
  int surface_vertices = 0;
  for (int v = 0; v < m.num_vertices(); ++v) {
    if (!m.is_surface_vertex(v)) continue;
    area += contact_areas[v];
    ++surface_vertices;
  }
  return surface_vertices > 0 ? area / surface_vertices : 0.0;
}

double FacingContactArea(const TetMesh& m, const Positions& positions, int vertex,
                         const Eigen::Vector3d& direction, double area) {
  const int begin = m.vertex_triangle_offsets()[vertex];
  const int end = m.vertex_triangle_offsets()[vertex + 1];
  if (begin == end) return area;
  double facing = 0.0;
  for (int i = begin; i < end; ++i) {
    const int f = m.vertex_triangles()[i];
    Eigen::Vector3d a = positions.row(m.surface()(f, 0));
    Eigen::Vector3d b = positions.row(m.surface()(f, 1));
    Eigen::Vector3d c = positions.row(m.surface()(f, 2));
    // (twice the triangle's area along its outward normal)
    facing += std::max(0.0, -(b - a).cross(c - a).dot(direction));
  }
  return std::max(facing / 6.0, kMinFacingShare * area);
}

const char* ContactAreaName(ContactArea area) {
  return area == ContactArea::kFacing ? "facing" : "whole";
}

double ContactAreaOf(ContactArea rule, const TetMesh& mesh, const Positions& positions, int vertex,
                     const Eigen::Vector3d& direction, double area) {
  return rule == ContactArea::kFacing ? FacingContactArea(mesh, positions, vertex, direction, area)
                                      : area;
}

std::shared_ptr<const FemModel> FemModel::Build(std::shared_ptr<const TetMesh> mesh,
                                                const Material& material, const char* where) {
  material.Validate(where);
  auto model = std::shared_ptr<FemModel>(new FemModel());
  model->mesh_ = std::move(mesh);
  model->material_ = material;
  model->mu_ = material.Mu();
  model->lambda_ = material.Lambda();
  const TetMesh& m = *model->mesh_;
  const int num_vertices = m.num_vertices();
  const int num_tets = m.num_tets();

  // gradients, masses, volume shares
  model->gradients_.resize(num_tets);
  model->masses_.setZero(num_vertices);
  for (int t = 0; t < num_tets; ++t) {
    Eigen::Vector3d X[4];
    for (int i = 0; i < 4; ++i) X[i] = m.positions().row(m.tets()(t, i)).transpose();
    model->gradients_[t] = ShapeGradients(X);
    double volume = m.rest_volumes()[t];
    for (int i = 0; i < 4; ++i) {
      model->masses_[m.tets()(t, i)] += material.density * volume / 4.0;
    }
  }
  model->total_mass_ = model->masses_.sum();
  model->characteristic_length_ = std::cbrt(m.total_volume());

  model->contact_areas_ = ComputeContactAreas(m);

  // sparsity: vertex v couples with itself and its edge neighbours
  const auto& offsets = m.adjacency_offsets();
  const auto& adjacency = m.adjacency();
  model->row_start_.assign(3 * num_vertices + 1, 0);
  model->diagonal_slot_.resize(num_vertices);
  std::vector<std::vector<int>> neighbours(num_vertices);
  for (int v = 0; v < num_vertices; ++v) {
    std::vector<int>& row = neighbours[v];
    row.assign(adjacency.begin() + offsets[v], adjacency.begin() + offsets[v + 1]);
    row.push_back(v);
    std::sort(row.begin(), row.end());
    model->diagonal_slot_[v] =
        3 * static_cast<int>(std::lower_bound(row.begin(), row.end(), v) - row.begin());
    for (int r = 0; r < 3; ++r) {
      model->row_start_[3 * v + r + 1] =
          model->row_start_[3 * v + r] + 3 * static_cast<int>(row.size());
    }
  }
  model->columns_.resize(model->row_start_.back());
  for (int v = 0; v < num_vertices; ++v) {
    for (int r = 0; r < 3; ++r) {
      int position = model->row_start_[3 * v + r];
      for (int u : neighbours[v]) {
        for (int c = 0; c < 3; ++c) model->columns_[position++] = 3 * u + c;
      }
    }
  }
  model->element_slots_.resize(num_tets);
  for (int t = 0; t < num_tets; ++t) {
    for (int a = 0; a < 4; ++a) {
      const std::vector<int>& row = neighbours[m.tets()(t, a)];
      for (int b = 0; b < 4; ++b) {
        int u = m.tets()(t, b);
        model->element_slots_[t][4 * a + b] =
            3 * static_cast<int>(std::lower_bound(row.begin(), row.end(), u) - row.begin());
      }
    }
  }
  // greedy colouring: each tet takes the smallest colour none of its
  // vertices' earlier tets has
  std::vector<int> color(num_tets, 0);
  std::vector<std::uint64_t> vertex_colors(num_vertices, 0);  // bit set of used colours
  int num_colors = 0;
  for (int t = 0; t < num_tets; ++t) {
    std::uint64_t used = 0;
    for (int i = 0; i < 4; ++i) used |= vertex_colors[m.tets()(t, i)];
    int c = 0;
    while (c < 63 && (used >> c & 1u)) ++c;
    color[t] = c;  // colour 63 collects the (rare) rest; assembled serially
    if (c < 63) {
      for (int i = 0; i < 4; ++i) vertex_colors[m.tets()(t, i)] |= std::uint64_t{1} << c;
    }
    num_colors = std::max(num_colors, c + 1);
  }
  // the tets sorted by colour (mesh order within a colour)
  std::vector<int> color_offsets;  // #colors + 1
  std::vector<int> colored_tets;   // #T
  GroupByKey(
      num_colors,
      [&](auto emit) {
        for (int t = 0; t < num_tets; ++t) emit(color[t], t);
      },
      color_offsets, colored_tets);

  // batches of four, in mesh order and within each colour
  auto append_batches = [](const int* tets, int count, std::vector<ElementBatch>& batches) {
    for (int k = 0; k < count; k += 4) {
      ElementBatch& batch = batches.emplace_back();
      for (int lane = 0; lane < 4 && k + lane < count; ++lane) batch.tets[lane] = tets[k + lane];
    }
  };
  std::vector<int> mesh_order(num_tets);
  for (int t = 0; t < num_tets; ++t) mesh_order[t] = t;
  append_batches(mesh_order.data(), num_tets, model->serial_batches_);
  model->color_batch_offsets_.assign(1, 0);
  for (int c = 0; c < num_colors; ++c) {
    append_batches(colored_tets.data() + color_offsets[c], color_offsets[c + 1] - color_offsets[c],
                   model->colored_batches_);
    model->color_batch_offsets_.push_back(static_cast<int>(model->colored_batches_.size()));
  }
  return model;
}

}  // namespace tetcosim
