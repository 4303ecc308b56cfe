#include "collision/penetration.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <string>

#include "collision/penetration_internal.h"
#include "mesh/error.h"

namespace tetcosim {
namespace {

// on several threads, the surfaces of up to this many objects with partners
// per thread are made alongside stage 1 (Solve)
constexpr int kMaxSurfacesAheadPerThread = 4;

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

PenetrationSolver::PenetrationSolver(PenetrationOptions options) {
  set_options(options);
}

void PenetrationSolver::set_options(const PenetrationOptions& options) {
  if (!(options.cell_size >= 0.0) || !std::isfinite(options.cell_size)) {
    char value[32];
    std::snprintf(value, sizeof(value), "%g", options.cell_size);
    throw Error(std::string("penetration solver: the cell size is ") + value +
                " m; give a finite length >= 0 (0: the average edge length)");
  }
  options_ = options;
}

const std::vector<PenetrationResult>& PenetrationSolver::Solve(
    std::span<const CollisionObject> objects) {
  Clock::time_point start = Clock::now();
  timings_ = {};
  stats_ = {};
  Prepare(objects);
  timings_.hash = SecondsSince(start);
  // stage 1 and the surfaces at once, on several threads, for scenes of a
  // few objects with partners: the surfaces are then made before it is
  // known which objects are penetrated, and in a pile of small bodies many
  // boxes overlap without penetration (120 spheres on two threads: 13%
  // slower, from surfaces made in vain). Not for closest features either,
  // which hash whole surfaces.
  const int threads =
      ThreadsFor(options_.num_threads, colliding_.num_chunks(), kMinChunksPerThread);
  if (threads > 1 &&
      static_cast<int>(broad_phase_.partnered().size()) <= kMaxSurfacesAheadPerThread * threads &&
      options_.method == DepthMethod::kConsistent) {
    FindCollidingPointsAndHashSurfaces(objects, threads);
  } else {
    colliding_.Find(options_.num_threads, timings_.hash, timings_.inside);
    HashSurfaces(objects, /*full=*/options_.method == DepthMethod::kClosest);
  }
  if (options_.method == DepthMethod::kConsistent) {
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
  std::vector<int>& vertex_offset = vertices_.offset;
  vertex_offset.resize(num_objects + 1);
  vertex_offset[0] = 0;
  vertices_.positions.resize(num_objects);
  double edge_sum = 0.0;
  long edge_count = 0;
  max_degree_ = 0;
  for (int o = 0; o < num_objects; ++o) {
    const CollisionObject& object = objects[o];
    if (object.mesh == nullptr || object.positions == nullptr ||
        object.positions->rows() != object.mesh->num_vertices()) [[unlikely]] {
      throw Error("penetration solver: object " + std::to_string(o) +
                  (object.mesh == nullptr || object.positions == nullptr
                       ? " has no mesh or no positions"
                       : " has " + std::to_string(object.positions->rows()) +
                             " positions for a mesh of " +
                             std::to_string(object.mesh->num_vertices()) + " vertices") +
                  "; give every object its mesh and one position per vertex");
    }
    vertex_offset[o + 1] = vertex_offset[o] + object.mesh->num_vertices();
    vertices_.positions[o] = object.positions;
    edge_sum +=
        object.mesh->average_edge_length() * static_cast<double>(object.mesh->edges().rows());
    edge_count += object.mesh->edges().rows();
    max_degree_ = std::max(max_degree_, object.mesh->max_degree());
  }
  const int num_vertices = vertex_offset[num_objects];
  if (vertex_offset != vertices_.object_filled_for) {  // (the same objects: already filled)
    vertices_.object.resize(num_vertices);
    for (int o = 0; o < num_objects; ++o) {
      std::fill(vertices_.object.begin() + vertex_offset[o],
                vertices_.object.begin() + vertex_offset[o + 1], o);
    }
    vertices_.object_filled_for = vertex_offset;
  }
  length_scale_ = edge_count > 0 ? edge_sum / static_cast<double>(edge_count) : 1.0;
  cell_size_ = options_.cell_size > 0.0 ? options_.cell_size : length_scale_;
  // broad phase: bounding boxes, and per object B its partners (the objects
  // whose boxes overlap B's and that may collide with it, B itself with
  // self-collision) and the region where they can reach into B
  boxes_.resize(num_objects);
  kept_.resize(num_objects);
  bool any_kept = false;  // (an object is active in kept_ this solve)
  for (int o = 0; o < num_objects; ++o) {
    KeptObject& kept = kept_[o];
    const bool keepable = objects[o].fixed || objects[o].frame != nullptr;
    kept.active = keepable && kept.Keep(objects[o]);
    if (!keepable) kept.mesh = nullptr;          // (seen moving: keep nothing)
    if (!kept.active) kept.outcode_offset = -1;  // (its outcodes: all written)
    any_kept |= kept.active;
    stats_.fixed_objects += kept.active && !kept.framed;
    stats_.framed_objects += kept.active && kept.framed;
    Eigen::Vector3d lo, hi;
    bool finite;
    if (kept.active && !kept.framed) {
      lo = kept.lo;
      hi = kept.hi;
      finite = kept.finite;
    } else {
      // the caller's pass over the positions, if it gives its box, else ours
      const RigidFrame* frame = objects[o].frame;
      const bool given = frame != nullptr && frame->bounds.has_value();
      if (given) CheckGivenBounds(objects[o], o);
      const PositionBounds bounds =
          given ? *frame->bounds : PositionBounds::Of(*objects[o].positions);
      lo = bounds.lo;
      hi = bounds.hi;
      finite = bounds.finite();
    }
    if (!finite) {
      // left out: an empty box meets no other
      ++stats_.non_finite_objects;
      lo.setConstant(std::numeric_limits<double>::infinity());
      hi = -lo;
    } else {
      Inflate(lo, hi);
    }
    boxes_[o] = {lo, hi, objects[o].rigid, objects[o].self_collision};
  }
  broad_phase_.Find(boxes_);
  colliding_.Begin(objects, vertices_, kept_, any_kept, broad_phase_, cell_size_);
}

void PenetrationSolver::CollectResults(std::span<const CollisionObject> /*objects*/) {
  results_.clear();
  double depth_sum = 0.0;
  for (size_t h = 0; h < colliding_.hits().size(); ++h) {
    if (layer_[h] < 0) {
      ++stats_.unresolved;
      continue;
    }
    const Hit& hit = colliding_.hits()[h];
    PenetrationResult result;
    result.object = vertices_.object[hit.vertex];
    result.vertex = hit.vertex - vertices_.offset[result.object];
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
  stats_.tet_tests = colliding_.tet_tests();
  stats_.mean_depth = results_.empty() ? 0.0 : depth_sum / static_cast<double>(results_.size());
}

}  // namespace tetcosim
