#include "collision/kept_object.h"

#include <algorithm>
#include <limits>
#include <span>

#include "collision/penetration_internal.h"
#include "mesh/group_by_key.h"
#include "mesh/same_bits.h"

namespace tetcosim {
namespace {

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

}  // namespace

bool KeptObject::Keep(const CollisionObject& object) {
  const TetMesh& object_mesh = *object.mesh;
  const Positions& x = *object.positions;
  const int num_vertices = object_mesh.num_vertices();
  const bool with_frame = !object.fixed;  // (else it has a frame)
  if (with_frame) {
    const RigidFrame& frame = *object.frame;
    const double off_identity =
        (frame.rotation.transpose() * frame.rotation - Eigen::Matrix3d::Identity())
            .cwiseAbs()
            .maxCoeff();
    if (!(off_identity <= kRotationTolerance) || !frame.translation.allFinite()) {
      mesh = nullptr;  // (not a rotation: keep nothing)
      return false;
    }
    rotation = frame.rotation;
    translation = frame.translation;
  }
  const bool seen = mesh == object.mesh && positions == object.positions && framed == with_frame;
  framed = with_frame;
  // a vertex's position, in the body frame if framed
  auto position = [&](int v) { return ToBody(x.row(v).transpose()); };
  if (seen) {
    // (the rounding of the samples as kept, and as now)
    const double magnitude =
        std::max(pad / kFramePad, body_scale + translation.cwiseAbs().maxCoeff());
    const double tolerance = with_frame ? kFrameRounding * magnitude : 0.0;
    bool still = true;
    for (size_t i = 0; i < sample_vertex.size(); ++i) {
      const Eigen::Vector3d p = position(sample_vertex[i]);
      still &= with_frame ? (p - sample[i]).cwiseAbs().maxCoeff() <= tolerance
                          : SameBits({p.data(), 3}, {sample[i].data(), 3});
    }
    if (still && built && 8.0 * tolerance <= pad) return true;
    for (size_t i = 0; i < sample_vertex.size(); ++i) {
      sample[i] = position(sample_vertex[i]);
    }
    if (!still) {
      built = false;
      return false;
    }
  } else {
    mesh = object.mesh;
    positions = object.positions;
    const int num_samples = std::min(kSampledVertices, num_vertices);
    sample_vertex.resize(num_samples);
    sample.resize(num_samples);
    for (int i = 0; i < num_samples; ++i) {
      // spread over the numbering, the last vertex among them
      sample_vertex[i] = static_cast<int>(SpreadVertex(i + 1, num_samples, num_vertices));
      sample[i] = position(sample_vertex[i]);
    }
  }
  // keep it
  built = true;
  outcode_offset = -1;  // (another object's, or the outcodes written meanwhile)
  const PositionBounds bounds = PositionBounds::Of(x);
  lo = bounds.lo;
  hi = bounds.hi;
  finite = bounds.finite();
  pad = 0.0;
  if (with_frame) {
    if (!finite) {  // (left out this solve; not kept, as its positions may change)
      mesh = nullptr;
      return false;
    }
    body_scale = 0.0;
    for (int v = 0; v < num_vertices; ++v) {
      body_scale = std::max(body_scale, position(v).cwiseAbs().maxCoeff());
    }
    pad = kFramePad * (body_scale + translation.cwiseAbs().maxCoeff());
  }
  const Eigen::Vector3d grow = Eigen::Vector3d::Constant(pad);
  const int num_runs = object_mesh.num_spatial_runs();
  const std::vector<int>& run_vertices = object_mesh.spatial_run_vertices();
  const std::vector<int>& run_offsets = object_mesh.spatial_run_vertex_offsets();
  run_lo.resize(num_runs);
  run_hi.resize(num_runs);
  std::vector<char> in_run(num_vertices, 0);
  for (int r = 0; r < num_runs; ++r) {
    Eigen::Vector3d run_box_lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
    Eigen::Vector3d run_box_hi = -run_box_lo;
    for (int i = run_offsets[r]; i < run_offsets[r + 1]; ++i) {
      run_box_lo = run_box_lo.cwiseMin(position(run_vertices[i]));
      run_box_hi = run_box_hi.cwiseMax(position(run_vertices[i]));
      in_run[run_vertices[i]] = 1;
    }
    run_lo[r] = run_box_lo - grow;
    run_hi[r] = run_box_hi + grow;
  }
  // (a non-finite object is left out of the solve: its trees are empty,
  // no chunk to search, no face to find)
  auto if_finite = [&](const std::vector<Eigen::Vector3d>& boxes) {
    return finite ? std::span<const Eigen::Vector3d>(boxes) : std::span<const Eigen::Vector3d>();
  };
  runs.Build(if_finite(run_lo), if_finite(run_hi));
  loose_vertices.clear();
  for (int v = 0; v < num_vertices; ++v) {
    if (!in_run[v]) loose_vertices.push_back(v);
  }
  // each surface face in the chunk of its tet (the last chunk also takes
  // the remainder of the spatial order)
  std::vector<int> tet_run(object_mesh.num_tets());
  for (int n = 0; n < object_mesh.num_tets(); ++n) {
    tet_run[object_mesh.spatial_tet_order()[n]] = std::min(n / kChunkTets, num_runs - 1);
  }
  const int num_faces = static_cast<int>(object_mesh.surface().rows());
  GroupByKey(
      num_runs,
      [&](auto emit) {
        for (int f = 0; f < num_faces; ++f) emit(tet_run[object_mesh.surface_tet()[f]], f);
      },
      run_face_offset, run_faces);
  face_lo.resize(num_faces);
  face_hi.resize(num_faces);
  for (int f = 0; f < num_faces && finite; ++f) {
    Eigen::Vector3d corner[3];
    for (int k = 0; k < 3; ++k) corner[k] = position(object_mesh.surface()(f, k));
    InflatedBounds(corner, face_lo[f], face_hi[f]);
    face_lo[f] -= grow;
    face_hi[f] += grow;
  }
  faces.Build(if_finite(face_lo), if_finite(face_hi));
  return true;
}

}  // namespace tetcosim
