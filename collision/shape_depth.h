#pragma once

// Consistent penetration depth (method.md, stages 2 to 4) of one mesh's
// vertices inside a solid given by functions instead of a tetrahedral mesh:
// a MuJoCo geom without a proxy (mujoco_bridge/geom_shape.h). The caller
// does stage 1 (which vertices are inside, with each one's closest-feature
// depth and direction) and answers stage 2's question, where an
// intersection edge enters the solid and the solid's outward normal there;
// stages 3 and 4 are the penetration solver's (collision/penetration.h),
// on this one mesh:
//   3. a border point p (a neighbour along a mesh edge outside), crossings
//      x_i with normals n_i: d = sum w_i (x_i - p).n_i / sum w_i,
//      r = normalise(sum w_i n_i), w_i = 1 / |x_i - p|^2;
//   4. the other points layer by layer, each from earlier layers only:
//      d = sum mu_j ((p_j - p).r_j + d_j) / sum mu_j,
//      r = normalise(sum mu_j r_j), mu_j = 1 / |p_j - p|^2.
// Points the method does not reach (a component with no border point, or
// directions that cancel) keep the closest feature's value, flagged
// kFallback. Deterministic (points in ascending order, layers from earlier
// layers only); no heap allocation once the buffers have grown.

#include <Eigen/Core>
#include <functional>
#include <span>
#include <vector>

#include "collision/penetration.h"
#include "mesh/tet_mesh.h"

namespace tetcosim {

struct ShapePoint {
  int vertex = -1;  // into the mesh
  // in: the closest feature's depth (m, >= 0) and unit way out; out: the
  // method's
  double depth = 0.0;
  Eigen::Vector3d direction = Eigen::Vector3d::UnitZ();
  DepthSource source = DepthSource::kFallback;  // out
};

// Where the edge from `outside` to `inside` enters the solid (the crossing
// nearest `outside`) and the solid's outward unit normal there; false if it
// finds none (as where `inside` lies on the surface within rounding).
using ShapeCrossing =
    std::function<bool(const Eigen::Vector3d& outside, const Eigen::Vector3d& inside,
                       Eigen::Vector3d& crossing, Eigen::Vector3d& normal)>;

class ShapeDepthSolver {
 public:
  // points: the vertices of `mesh` (at positions x) inside the solid, in
  // ascending vertex order, with their closest-feature values; on return,
  // the method's values where it reaches (above).
  void Solve(const TetMesh& mesh, const Positions& x, std::span<ShapePoint> points,
             const ShapeCrossing& crossing);

 private:
  std::vector<int> point_of_;       // per mesh vertex: its index in points, or -1
  std::vector<int> layer_;          // per point: the layer that gave it its value, or -1
  std::vector<int> frontier_;       // this layer's points (ascending once sorted)
  std::vector<int> next_;           // the next layer's
  std::vector<int> listed_;         // per point: the layer it was last listed for
  std::vector<ShapePoint> values_;  // the layer's values, until the layer is done
};

}  // namespace tetcosim
