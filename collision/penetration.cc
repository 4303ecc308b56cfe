#include "collision/penetration.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdio>
#include <limits>
#include <string>

#include "collision/penetration_internal.h"
#include "collision/simd4.h"
#include "mesh/error.h"
#include "mesh/group_by_key.h"
#include "mesh/same_bits.h"

namespace tetcosim {
namespace {

// on several threads, the surfaces of up to this many objects with partners
// per thread are made alongside stage 1 (Solve)
constexpr int kMaxSurfacesAheadPerThread = 4;

}  // namespace

// (Row by row, in one pass: Eigen's column-wise reduction of a row-major
// matrix walks each column on its own, six passes. Grown in a local and
// copied out: grown in the returned object, which the positions might
// alias as far as the compiler knows, it was kept in memory, 0.5% more
// instructions a solve on the scenes.)
PositionBounds PositionBounds::Of(const Positions& x) {
  PositionBounds grown;
  for (int v = 0; v < x.rows(); ++v) grown.Add(x.row(v).transpose());
  PositionBounds bounds = grown;
  return bounds;
}

// a fixed or framed object's vertices compared every solve
// (CollisionObject::fixed, ::frame)
constexpr int kKeptSamples = 16;
// Vertex i of n + 1 spread evenly over a numbering of num_vertices: i = 0 is
// the first, i = n the last (the samples of a kept object and of a given
// box's check).
long SpreadVertex(long i, long n, long num_vertices) {
  return (num_vertices - 1) * i / n;
}
// A framed object's positions taken into its body frame differ from one
// solve to the next by rounding, a few ulp of the coordinates' magnitude
// (body-frame and translation): a sample may differ by kFrameRounding
// times that magnitude, the kept boxes are grown by kFramePad times it
// (at keeping), and they are kept anew when the magnitude has grown so far
// (a body carried far away) that the rounding could reach an eighth of the
// growth.
constexpr double kFrameRounding = 1e-12;
constexpr double kFramePad = 1e-9;
// how far R^T R may be from the identity, entry by entry, for a rotation
constexpr double kRotationTolerance = 1e-9;

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

void PenetrationSolver::ResizePadded(std::vector<double>& values, int n) {
  values.resize(n + kSimdPadding);
  std::fill(values.begin() + n, values.end(), std::numeric_limits<double>::quiet_NaN());
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
  if (threads > 1 && static_cast<int>(partnered_.size()) <= kMaxSurfacesAheadPerThread * threads &&
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
  normals_.resize(num_objects);
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
  // broad phase: bounding boxes; per object B its partners (the objects
  // whose boxes overlap B's and that may collide with it, B itself with
  // self-collision), found by sweep and prune (below), and the region where
  // they can reach into B: the union of the boxes' overlaps.
  object_lo_.resize(num_objects);
  object_hi_.resize(num_objects);
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();  // (of the boxes' centres, left out aside)
  int num_in = 0;
  kept_.resize(num_objects);
  any_kept_ = false;
  for (int o = 0; o < num_objects; ++o) {
    KeptObject& kept = kept_[o];
    const bool keepable = objects[o].fixed || objects[o].frame != nullptr;
    kept.active = keepable && KeepObject(objects[o], kept);
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
      // left out: an empty box meets no other, and sorts last
      ++stats_.non_finite_objects;
      lo.setConstant(std::numeric_limits<double>::infinity());
      hi = -lo;
    } else {
      Inflate(lo, hi);
      mean += 0.5 * (lo + hi);
      ++num_in;
    }
    object_lo_[o] = lo;
    object_hi_[o] = hi;
  }
  mean /= std::max(1, num_in);
  // the sweep axis: the one along which the boxes' centres spread most
  // (their variance), so that the fewest boxes start before a box ends
  // along it (a pile of 9600 spheres, 20 x 80 x 6, swept along x: 360
  // boxes tested a box, 13 overlapping it, and the broad phase was 18% of
  // the solve's instructions; along y, 10%)
  Eigen::Vector3d spread = Eigen::Vector3d::Zero();
  for (int o = 0; o < num_objects; ++o) {
    if (object_lo_[o].x() > object_hi_[o].x()) continue;  // (left out)
    spread += (0.5 * (object_lo_[o] + object_hi_[o]) - mean).cwiseAbs2();
  }
  int axis = 0;
  spread.maxCoeff(&axis);  // (the first of equal ones)
  pairs_.clear();
  sweep_order_.resize(num_objects);
  for (int o = 0; o < num_objects; ++o) sweep_order_[o] = o;
  std::sort(sweep_order_.begin(), sweep_order_.end(), [&](int a, int b) {
    const double a_lo = object_lo_[a][axis], b_lo = object_lo_[b][axis];
    return a_lo != b_lo ? a_lo < b_lo : a < b;
  });
  // the boxes in sweep order by coordinate: a box is tested against the
  // boxes after it that start before it ends along the axis, four at a
  // time (in a pile of 120 spheres, about 50 of them per box)
  for (int k = 0; k < 3; ++k) {
    ResizePadded(sweep_lo_[k], num_objects);
    ResizePadded(sweep_hi_[k], num_objects);
    for (int i = 0; i < num_objects; ++i) {
      sweep_lo_[k][i] = object_lo_[sweep_order_[i]][k];
      sweep_hi_[k][i] = object_hi_[sweep_order_[i]][k];
    }
  }
  const std::vector<double>& sweep_lo = sweep_lo_[axis];
  for (int i = 0; i < num_objects; ++i) {
    const int a = sweep_order_[i];
    if (object_lo_[a].x() > object_hi_[a].x()) continue;  // (left out: sorted last)
    if (objects[a].self_collision) pairs_.push_back({a, a});
    // (the boxes that start before this one ends, by bisection)
    const int end =
        static_cast<int>(std::upper_bound(sweep_lo.begin() + i + 1, sweep_lo.begin() + num_objects,
                                          object_hi_[a][axis]) -
                         sweep_lo.begin());
    const Box4 box(object_lo_[a], object_hi_[a]);
    for (int j = i + 1; j < end; j += 4) {
      for (unsigned bits = box.Overlapping(sweep_lo_, sweep_hi_, j, end); bits != 0;
           bits &= bits - 1) {
        const int b = sweep_order_[j + std::countr_zero(bits)];
        if (objects[a].rigid && objects[b].rigid) continue;  // the rigid engine's pair
        pairs_.push_back({a, b});
        pairs_.push_back({b, a});
      }
    }
  }
  // per object its partners, with the overlap of the two boxes, in the
  // order found (deterministic)
  GroupByKey(
      num_objects,
      [&](auto emit) {
        for (int i = 0; i < static_cast<int>(pairs_.size()); ++i) emit(pairs_[i][0], i);
      },
      partner_offset_, partner_pair_);
  partnered_.clear();
  for (int o = 0; o < num_objects; ++o) {
    if (partner_offset_[o + 1] > partner_offset_[o]) partnered_.push_back(o);
  }
  partners_.resize(pairs_.size());
  const double inf = std::numeric_limits<double>::infinity();
  search_lo_.assign(num_objects, Eigen::Vector3d::Constant(inf));
  search_hi_.assign(num_objects, Eigen::Vector3d::Constant(-inf));
  for (size_t k = 0; k < partners_.size(); ++k) {
    const auto [b, a] = pairs_[partner_pair_[k]];
    Partner& partner = partners_[k];
    partner.object = a;
    partner.lo = object_lo_[a].cwiseMax(object_lo_[b]);
    partner.hi = object_hi_[a].cwiseMin(object_hi_[b]);
    search_lo_[b] = search_lo_[b].cwiseMin(partner.lo);
    search_hi_[b] = search_hi_[b].cwiseMax(partner.hi);
  }
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
    Eigen::Vector3d lo = search_lo_[o], hi = search_hi_[o];
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

void PenetrationSolver::CheckGivenBounds(const CollisionObject& object, int o) {
  // kKeptSamples vertices spread over the numbering, the first and last
  // among them (a box kept from another placement, or of other positions,
  // leaves out some of them)
  const PositionBounds& bounds = *object.frame->bounds;
  const Positions& x = *object.positions;
  const long num_vertices = x.rows();
  for (long i = 0; i <= kKeptSamples && num_vertices > 0; ++i) {
    const long v = SpreadVertex(i, kKeptSamples, num_vertices);
    const Eigen::Vector3d p = x.row(v).transpose();
    const bool finite = p.allFinite();
    const bool inside =
        (bounds.lo.array() <= p.array()).all() && (p.array() <= bounds.hi.array()).all();
    if (finite ? inside : !bounds.finite()) continue;
    char at[96];
    std::snprintf(at, sizeof(at), " (at %g, %g, %g)", p.x(), p.y(), p.z());
    throw Error("penetration solver: object " + std::to_string(o) +
                ": its frame's bounds do not hold its vertex " + std::to_string(v) + at +
                "; give RigidFrame::bounds as PositionBounds::Add of every position as given, "
                "or leave it unset");
  }
}

bool PenetrationSolver::KeepObject(const CollisionObject& object, KeptObject& kept) {
  const TetMesh& mesh = *object.mesh;
  const Positions& x = *object.positions;
  const int num_vertices = mesh.num_vertices();
  const bool framed = !object.fixed;  // (else it has a frame)
  if (framed) {
    const RigidFrame& frame = *object.frame;
    const double off_identity =
        (frame.rotation.transpose() * frame.rotation - Eigen::Matrix3d::Identity())
            .cwiseAbs()
            .maxCoeff();
    if (!(off_identity <= kRotationTolerance) || !frame.translation.allFinite()) {
      kept.mesh = nullptr;  // (not a rotation: keep nothing)
      return false;
    }
    kept.rotation = frame.rotation;
    kept.translation = frame.translation;
  }
  const bool seen =
      kept.mesh == object.mesh && kept.positions == object.positions && kept.framed == framed;
  kept.framed = framed;
  // a vertex's position, in the body frame if framed
  auto position = [&](int v) { return kept.ToBody(x.row(v).transpose()); };
  if (seen) {
    // (the rounding of the samples as kept, and as now)
    const double magnitude =
        std::max(kept.pad / kFramePad, kept.body_scale + kept.translation.cwiseAbs().maxCoeff());
    const double tolerance = framed ? kFrameRounding * magnitude : 0.0;
    bool still = true;
    for (size_t i = 0; i < kept.sample_vertex.size(); ++i) {
      const Eigen::Vector3d p = position(kept.sample_vertex[i]);
      still &= framed ? (p - kept.sample[i]).cwiseAbs().maxCoeff() <= tolerance
                      : SameBits({p.data(), 3}, {kept.sample[i].data(), 3});
    }
    if (still && kept.built && 8.0 * tolerance <= kept.pad) return true;
    for (size_t i = 0; i < kept.sample_vertex.size(); ++i) {
      kept.sample[i] = position(kept.sample_vertex[i]);
    }
    if (!still) {
      kept.built = false;
      return false;
    }
  } else {
    kept.mesh = object.mesh;
    kept.positions = object.positions;
    const int num_samples = std::min(kKeptSamples, num_vertices);
    kept.sample_vertex.resize(num_samples);
    kept.sample.resize(num_samples);
    for (int i = 0; i < num_samples; ++i) {
      // spread over the numbering, the last vertex among them
      kept.sample_vertex[i] = static_cast<int>(SpreadVertex(i + 1, num_samples, num_vertices));
      kept.sample[i] = position(kept.sample_vertex[i]);
    }
  }
  // keep it
  kept.built = true;
  kept.outcode_offset = -1;  // (another object's, or the outcodes written meanwhile)
  const PositionBounds bounds = PositionBounds::Of(x);
  kept.lo = bounds.lo;
  kept.hi = bounds.hi;
  kept.finite = bounds.finite();
  kept.pad = 0.0;
  if (framed) {
    if (!kept.finite) {  // (left out this solve; not kept, as its positions may change)
      kept.mesh = nullptr;
      return false;
    }
    kept.body_scale = 0.0;
    for (int v = 0; v < num_vertices; ++v) {
      kept.body_scale = std::max(kept.body_scale, position(v).cwiseAbs().maxCoeff());
    }
    kept.pad = kFramePad * (kept.body_scale + kept.translation.cwiseAbs().maxCoeff());
  }
  const Eigen::Vector3d pad = Eigen::Vector3d::Constant(kept.pad);
  const int num_runs = mesh.num_spatial_runs();
  const std::vector<int>& run_vertices = mesh.spatial_run_vertices();
  const std::vector<int>& run_offsets = mesh.spatial_run_vertex_offsets();
  kept.run_lo.resize(num_runs);
  kept.run_hi.resize(num_runs);
  std::vector<char> in_run(num_vertices, 0);
  for (int r = 0; r < num_runs; ++r) {
    Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
    Eigen::Vector3d hi = -lo;
    for (int i = run_offsets[r]; i < run_offsets[r + 1]; ++i) {
      lo = lo.cwiseMin(position(run_vertices[i]));
      hi = hi.cwiseMax(position(run_vertices[i]));
      in_run[run_vertices[i]] = 1;
    }
    kept.run_lo[r] = lo - pad;
    kept.run_hi[r] = hi + pad;
  }
  // (a non-finite object is left out of the solve: its trees are empty,
  // no chunk to search, no face to find)
  auto if_finite = [&](const std::vector<Eigen::Vector3d>& boxes) {
    return kept.finite ? std::span<const Eigen::Vector3d>(boxes)
                       : std::span<const Eigen::Vector3d>();
  };
  kept.runs.Build(if_finite(kept.run_lo), if_finite(kept.run_hi));
  kept.loose_vertices.clear();
  for (int v = 0; v < num_vertices; ++v) {
    if (!in_run[v]) kept.loose_vertices.push_back(v);
  }
  // each surface face in the chunk of its tet (the last chunk also takes
  // the remainder of the spatial order)
  std::vector<int> tet_run(mesh.num_tets());
  for (int n = 0; n < mesh.num_tets(); ++n) {
    tet_run[mesh.spatial_tet_order()[n]] = std::min(n / kChunkTets, num_runs - 1);
  }
  const int num_faces = static_cast<int>(mesh.surface().rows());
  kept.run_face_offset.assign(num_runs + 1, 0);
  for (int f = 0; f < num_faces; ++f) ++kept.run_face_offset[tet_run[mesh.surface_tet()[f]] + 1];
  for (int r = 0; r < num_runs; ++r) kept.run_face_offset[r + 1] += kept.run_face_offset[r];
  kept.run_faces.resize(num_faces);
  std::vector<int> next(kept.run_face_offset.begin(), kept.run_face_offset.end() - 1);
  for (int f = 0; f < num_faces; ++f) kept.run_faces[next[tet_run[mesh.surface_tet()[f]]]++] = f;
  kept.face_lo.resize(num_faces);
  kept.face_hi.resize(num_faces);
  for (int f = 0; f < num_faces && kept.finite; ++f) {
    Eigen::Vector3d corner[3];
    for (int k = 0; k < 3; ++k) corner[k] = position(mesh.surface()(f, k));
    InflatedBounds(corner, kept.face_lo[f], kept.face_hi[f]);
    kept.face_lo[f] -= pad;
    kept.face_hi[f] += pad;
  }
  kept.faces.Build(if_finite(kept.face_lo), if_finite(kept.face_hi));
  return true;
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
