#include "collision/shape_depth.h"

#include <algorithm>

#include "collision/geometry.h"

namespace tetcosim {

void ShapeDepthSolver::Solve(const TetMesh& mesh, const Positions& x, std::span<ShapePoint> points,
                             const ShapeCrossing& crossing) {
  const int num_points = static_cast<int>(points.size());
  if (num_points == 0) return;
  if (point_of_.size() != static_cast<size_t>(mesh.num_vertices())) {
    point_of_.assign(mesh.num_vertices(), -1);
  }
  for (int k = 0; k < num_points; ++k) point_of_[points[k].vertex] = k;
  layer_.assign(num_points, -1);
  const std::vector<int>& offsets = mesh.adjacency_offsets();
  const std::vector<int>& adjacency = mesh.adjacency();
  // closer than this, two points are one (a crossing at p: p on the
  // surface, depth 0), as in the penetration solver
  const double coincident = 1e-9 * mesh.average_edge_length();

  // stages 2 and 3: border points from their intersection edges
  for (int k = 0; k < num_points; ++k) {
    const int v = points[k].vertex;
    const Eigen::Vector3d p = x.row(v).transpose();
    BorderPointSums sums(coincident);
    for (int n = offsets[v]; n < offsets[v + 1]; ++n) {
      const int q = adjacency[n];
      if (point_of_[q] >= 0) continue;  // (inside too: not an intersection edge)
      Eigen::Vector3d at, normal;
      if (crossing(x.row(q).transpose(), p, at, normal)) sums.Add(at - p, normal);
    }
    if (!sums.any()) continue;
    ShapePoint& point = points[k];
    sums.Result(point.depth, point.direction);
    point.source = DepthSource::kBorder;
    layer_[k] = 0;
  }

  // stage 4: the points next to those with a value, layer by layer. A
  // layer is the points without a value next to one that got its value in
  // the layer before (a point whose neighbours' directions cancelled is
  // tried again only once another neighbour has a value: nothing else
  // could change its sums).
  listed_.assign(num_points, 0);
  auto list_neighbours = [&](int k, int layer, std::vector<int>& list) {
    const int v = points[k].vertex;
    for (int n = offsets[v]; n < offsets[v + 1]; ++n) {
      const int j = point_of_[adjacency[n]];
      if (j < 0 || layer_[j] >= 0 || listed_[j] == layer) continue;
      listed_[j] = layer;
      list.push_back(j);
    }
  };
  frontier_.clear();
  for (int k = 0; k < num_points; ++k) {
    if (layer_[k] == 0) list_neighbours(k, 1, frontier_);
  }
  for (int layer = 1; !frontier_.empty(); ++layer) {
    std::sort(frontier_.begin(), frontier_.end());
    values_.clear();
    for (int k : frontier_) {
      const int v = points[k].vertex;
      const Eigen::Vector3d p = x.row(v).transpose();
      PropagatedPointSums sums(coincident);
      for (int n = offsets[v]; n < offsets[v + 1]; ++n) {
        const int j = point_of_[adjacency[n]];
        if (j < 0 || layer_[j] < 0) continue;  // (outside, or no value before this layer)
        sums.Add(x.row(adjacency[n]).transpose() - p, points[j].depth, points[j].direction);
      }
      ShapePoint value = points[k];
      // (directions that cancel: no value yet, the closest feature's kept)
      value.source = sums.Result(value.depth, value.direction) ? DepthSource::kPropagated
                                                               : DepthSource::kFallback;
      values_.push_back(value);
    }
    for (size_t i = 0; i < frontier_.size(); ++i) {
      if (values_[i].source != DepthSource::kPropagated) continue;
      points[frontier_[i]] = values_[i];
      layer_[frontier_[i]] = layer;
    }
    next_.clear();
    for (int k : frontier_) {
      if (layer_[k] == layer) list_neighbours(k, layer + 1, next_);
    }
    std::swap(frontier_, next_);
  }
  for (int k = 0; k < num_points; ++k) point_of_[points[k].vertex] = -1;
}

}  // namespace tetcosim
