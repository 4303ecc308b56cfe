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
  const int threads = ThreadsFor(options_.num_threads, chunk_offset_.back(), kMinChunksPerThread);
  if (threads > 1 &&
      static_cast<int>(broad_phase_.partnered().size()) <= kMaxSurfacesAheadPerThread * threads &&
      options_.method == DepthMethod::kConsistent) {
    FindCollidingPointsAndHashSurfaces(objects, threads);
  } else {
    FindCollidingPoints(objects);
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
  vertex_offset_.resize(num_objects + 1);
  vertex_offset_[0] = 0;
  positions_.resize(num_objects);
  double edge_sum = 0.0;
  long edge_count = 0;
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
    vertex_offset_[o + 1] = vertex_offset_[o] + object.mesh->num_vertices();
    positions_[o] = object.positions;
    edge_sum +=
        object.mesh->average_edge_length() * static_cast<double>(object.mesh->edges().rows());
    edge_count += object.mesh->edges().rows();
  }
  const int num_vertices = vertex_offset_[num_objects];
  // stage 1's chunks of tets, object after object: the runs of each
  // object's spatial order (TetMesh::num_spatial_runs)
  chunk_offset_.resize(num_objects + 1);
  chunk_offset_[0] = 0;
  for (int o = 0; o < num_objects; ++o) {
    chunk_offset_[o + 1] = chunk_offset_[o] + objects[o].mesh->num_spatial_runs();
  }
  if (vertex_offset_ != object_of_offset_) {  // (the same objects: already filled)
    vertex_object_.resize(num_vertices);
    for (int o = 0; o < num_objects; ++o) {
      std::fill(vertex_object_.begin() + vertex_offset_[o],
                vertex_object_.begin() + vertex_offset_[o + 1], o);
    }
    object_of_offset_ = vertex_offset_;
  }
  length_scale_ = edge_count > 0 ? edge_sum / static_cast<double>(edge_count) : 1.0;
  cell_size_ = options_.cell_size > 0.0 ? options_.cell_size : length_scale_;
  inverse_cell_size_ = 1.0 / cell_size_;  // (as SpatialHash::Reset computes it)
  // broad phase: bounding boxes, and per object B its partners (the objects
  // whose boxes overlap B's and that may collide with it, B itself with
  // self-collision) and the region where they can reach into B
  boxes_.resize(num_objects);
  kept_.resize(num_objects);
  any_kept_ = false;
  for (int o = 0; o < num_objects; ++o) {
    KeptObject& kept = kept_[o];
    const bool keepable = objects[o].fixed || objects[o].frame != nullptr;
    kept.active = keepable && kept.Keep(objects[o]);
    if (!keepable) kept.mesh = nullptr;          // (seen moving: keep nothing)
    if (!kept.active) kept.outcode_offset = -1;  // (its outcodes: all written)
    any_kept_ |= kept.active;
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
  if (!any_kept_) return;
  // a kept object's chunks that stage 1 searches: those whose box meets
  // its search box, found in its tree. (A fixed object's: exactly those
  // that have a vertex in the search box, as a chunk's vertices all lie
  // beyond one side of the search box just when the chunk's box does not
  // meet it; a framed object's: a few more, its search box taken into the
  // body frame and grown.)
  search_chunks_.clear();
  for (int o = 0; o < num_objects; ++o) {
    KeptObject& kept = kept_[o];
    if (!kept.active) {
      for (int c = chunk_offset_[o]; c < chunk_offset_[o + 1]; ++c) search_chunks_.push_back(c);
      continue;
    }
    kept.searched.clear();
    Eigen::Vector3d lo = broad_phase_.search_lo(o), hi = broad_phase_.search_hi(o);
    if (kept.framed && (lo.array() <= hi.array()).all()) {
      // the search box in the body frame: the box around it there, grown
      // as the kept boxes are
      const Eigen::Vector3d centre = kept.ToBody(0.5 * (lo + hi));
      const Eigen::Vector3d half = kept.rotation.transpose().cwiseAbs() * (0.5 * (hi - lo)) +
                                   Eigen::Vector3d::Constant(kept.pad);
      lo = centre - half;
      hi = centre + half;
    }
    kept.runs.Overlapping(lo, hi, [&](int run) { kept.searched.push_back(run); });
    std::sort(kept.searched.begin(), kept.searched.end());
    for (int run : kept.searched) search_chunks_.push_back(chunk_offset_[o] + run);
  }
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
