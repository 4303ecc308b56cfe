#pragma once

// Small geometric predicates and queries used by the penetration solver.
// Plain floating point; the tolerances are explained where they are used.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <limits>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace tetcosim {

// A point is inside a tetrahedron when its barycentric coordinates are all
// at least -kBarycentricTolerance: a point on a face shared by two
// tetrahedra is then inside at least one of them despite rounding.
constexpr double kBarycentricTolerance = 1e-12;

// a . b, summed in Eigen's order ((x + y) + z), in scalar registers. Eigen
// loads the first two coordinates of each vector as one packet; when a
// vector was just computed (a cross product), its coordinates were stored
// one by one, and the packet load waits until both stores have retired (a
// failed store-to-load forward: perf put an eighth of stage 1's samples on
// it, in TetCoordinates' determinant).
inline double Dot3(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return (a.x() * b.x() + a.y() * b.y()) + a.z() * b.z();
}

// Barycentric coordinates in one tetrahedron (a, b, c, d), for many points:
// p = l0 a + l1 b + l2 c + l3 d with l0 + l1 + l2 + l3 = 1. What depends on
// the tetrahedron alone is computed once.
class TetCoordinates {
 public:
  TetCoordinates() = default;  // unset: assign before use
  TetCoordinates(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& c,
                 const Eigen::Vector3d& d)
      : a_(a), e1_(b - a), e2_(c - a), e3_(d - a), e23_(e2_.cross(e3_)) {
    const double det = Dot3(e1_, e23_);
    degenerate_ = det == 0.0 || !std::isfinite(det);
    inverse_det_ = degenerate_ ? 0.0 : 1.0 / det;
  }
  // zero volume (or not finite): no coordinates
  bool degenerate() const { return degenerate_; }

  // The coordinates of p (the tetrahedron must not be degenerate):
  // [b-a c-a d-a] (l1 l2 l3)^T = p - a by Cramer's rule.
  Eigen::Vector4d operator()(const Eigen::Vector3d& p) const {
    const Eigen::Vector3d r = p - a_;
    Eigen::Vector4d l;
    l[1] = Dot3(r, e23_) * inverse_det_;
    l[2] = Dot3(e1_, r.cross(e3_)) * inverse_det_;
    l[3] = Dot3(e1_, e2_.cross(r)) * inverse_det_;
    l[0] = 1.0 - l[1] - l[2] - l[3];
    return l;
  }

 private:
  Eigen::Vector3d a_, e1_, e2_, e3_, e23_;
  double inverse_det_;
  bool degenerate_;
};

// Barycentric coordinates of p in the tetrahedron (a, b, c, d). Returns
// false for a degenerate tetrahedron (zero volume).
inline bool TetBarycentric(const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                           const Eigen::Vector3d& c, const Eigen::Vector3d& d,
                           const Eigen::Vector3d& p, Eigen::Vector4d& l) {
  const TetCoordinates coordinates(a, b, c, d);
  if (coordinates.degenerate()) return false;
  l = coordinates(p);
  return true;
}

// SegmentTriangle's tolerances: crossings within a relative
// kSegmentTriangleTolerance of the triangle's edges or the segment's ends
// count; a segment whose direction is within kSegmentTriangleParallel
// (relative) of the triangle's plane is taken as parallel.
constexpr double kSegmentTriangleTolerance = 1e-12;
constexpr double kSegmentTriangleParallel = 1e-14;

// Where the segment from q to q + dir crosses the triangle (a, a + e1,
// a + e2), if it does: x = q + t dir, t in [0, 1], and the barycentric
// coordinates (1-u-v, u, v) of x in the triangle. Points on triangle edges
// and vertices count as hits (a relative tolerance of 1e-12), so an edge
// through a shared triangle edge hits both triangles rather than slipping
// between them. dir_length = |dir| and edge_lengths = |e1| |e2|, given so that
// callers testing one segment against many triangles, or one triangle
// against many segments, compute them once.
inline bool SegmentTriangle(const Eigen::Vector3d& q, const Eigen::Vector3d& dir, double dir_length,
                            const Eigen::Vector3d& a, const Eigen::Vector3d& e1,
                            const Eigen::Vector3d& e2, double edge_lengths, double& t, double& u,
                            double& v) {
  // Moller-Trumbore: q + t dir = (1-u-v) a + u (a + e1) + v (a + e2).
  // All conditions are evaluated and combined without branches: in stage 2
  // about four triangles are tested per edge, and the outcome of each early
  // exit is hard to predict (measured: the mispredictions cost more than
  // the flops they save). A zero det gives infinite or NaN u, v, t, which
  // fail the bounds, and is rejected anyway.
  constexpr double kTolerance = kSegmentTriangleTolerance;
  const Eigen::Vector3d h = dir.cross(e2);
  const double det = Dot3(e1, h);
  const double scale = edge_lengths * dir_length;
  const double inv = 1.0 / det;
  const Eigen::Vector3d s = q - a;
  u = Dot3(s, h) * inv;
  const Eigen::Vector3d k = s.cross(e1);
  v = Dot3(dir, k) * inv;
  t = Dot3(e2, k) * inv;
  return (std::abs(det) > kSegmentTriangleParallel * scale) &
         (scale != 0.0) &  // not parallel or degenerate
         (u >= -kTolerance) & (u <= 1.0 + kTolerance) & (v >= -kTolerance) &
         (u + v <= 1.0 + kTolerance) & (t >= -kTolerance) & (t <= 1.0 + kTolerance);
}

// The same for the segment from q to p and the triangle (a, b, c).
inline bool SegmentTriangle(const Eigen::Vector3d& q, const Eigen::Vector3d& p,
                            const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                            const Eigen::Vector3d& c, double& t, double& u, double& v) {
  Eigen::Vector3d dir = p - q;
  Eigen::Vector3d e1 = b - a, e2 = c - a;
  return SegmentTriangle(q, dir, dir.norm(), a, e1, e2, e1.norm() * e2.norm(), t, u, v);
}

// Whether the closed boxes [lo_a, hi_a] and [lo_b, hi_b] meet (touching
// counts). All six comparisons, combined without branches (a bitwise and,
// of ints: clang warns of one of bools): in the hot loops the outcome is
// close to random, and mispredicted branches cost more.
inline bool BoxesOverlap(const Eigen::Vector3d& lo_a, const Eigen::Vector3d& hi_a,
                         const Eigen::Vector3d& lo_b, const Eigen::Vector3d& hi_b) {
  return (static_cast<int>(lo_a.x() <= hi_b.x()) & static_cast<int>(lo_b.x() <= hi_a.x()) &
          static_cast<int>(lo_a.y() <= hi_b.y()) & static_cast<int>(lo_b.y() <= hi_a.y()) &
          static_cast<int>(lo_a.z() <= hi_b.z()) & static_cast<int>(lo_b.z() <= hi_a.z())) != 0;
}

// Below this length the interpolated vertex normals of SmoothNormal are
// taken to cancel (unit normals weighted by barycentric coordinates: a sum
// this short comes from opposite normals, as across a fold or a crushed
// tetrahedron, and has no direction left).
constexpr double kCancelledNormal = 1e-12;

// Stage 2's smooth normal at the point (1-u-v, u, v) of a surface triangle
// whose vertices have unit normals n0, n1, n2: their barycentric
// interpolation, normalised; where that cancels, the triangle's face normal,
// face_normal() (any length, e.g. e1 x e2; called only then). Returns false,
// leaving `normal` unspecified, if the face normal is zero too.
template <typename FaceNormal>
bool SmoothNormal(const Eigen::Vector3d& n0, const Eigen::Vector3d& n1, const Eigen::Vector3d& n2,
                  double u, double v, FaceNormal&& face_normal, Eigen::Vector3d& normal) {
  normal = (1.0 - u - v) * n0 + u * n1 + v * n2;
  double length = normal.norm();
  if (length < kCancelledNormal) {
    normal = face_normal();
    length = normal.norm();
    if (length == 0.0) return false;
  }
  normal /= length;
  return true;
}

// Stage 3 for one border point p (method.md): its crossings x_i, with the
// penetrated surface's unit normals n_i there, weighted w_i = 1 / |x_i - p|^2,
// give d(p) = sum w_i (x_i - p).n_i / sum w_i (at least 0) and
// r(p) = normalise(sum w_i n_i). A crossing closer to p than `on_surface`
// puts p on the surface: depth 0 and the nearest crossing's normal, which is
// also the direction where the weighted normals cancel.
class BorderPointSums {
 public:
  explicit BorderPointSums(double on_surface) : on_surface_(on_surface) {}
  // a crossing at p + to_crossing, where the surface's normal is `normal`
  void Add(const Eigen::Vector3d& to_crossing, const Eigen::Vector3d& normal) {
    const double distance = to_crossing.norm();
    if (distance < nearest_distance_) {
      nearest_distance_ = distance;
      nearest_normal_ = normal;
    }
    any_ = true;
    if (distance < on_surface_) return;
    const double w = 1.0 / (distance * distance);
    weight_sum_ += w;
    depth_sum_ += w * to_crossing.dot(normal);
    normal_sum_ += w * normal;
  }
  // whether a crossing was added: p is a border point
  bool any() const { return any_; }
  void Result(double& depth, Eigen::Vector3d& direction) const {
    if (nearest_distance_ < on_surface_ || weight_sum_ == 0.0) {
      depth = 0.0;
      direction = nearest_normal_;
      return;
    }
    depth = std::max(0.0, depth_sum_ / weight_sum_);
    const double normal_length = normal_sum_.norm();
    direction = normal_length > kCancelledNormal * weight_sum_
                    ? Eigen::Vector3d(normal_sum_ / normal_length)
                    : nearest_normal_;
  }

 private:
  double on_surface_;
  double weight_sum_ = 0.0;
  double depth_sum_ = 0.0;
  Eigen::Vector3d normal_sum_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d nearest_normal_ = Eigen::Vector3d::Zero();
  double nearest_distance_ = std::numeric_limits<double>::infinity();
  bool any_ = false;
};

// Stage 4 for one inner point p (method.md): its neighbours p_j that have
// values d_j, r_j, weighted mu_j = 1 / |p_j - p|^2, give
// d(p) = sum mu_j ((p_j - p).r_j + d_j) / sum mu_j (at least 0) and
// r(p) = normalise(sum mu_j r_j). A neighbour closer to p than `coincident`
// is the same point: p takes the first such neighbour's values.
class PropagatedPointSums {
 public:
  explicit PropagatedPointSums(double coincident) : coincident_sq_(coincident * coincident) {}
  // a neighbour at p + to_neighbour with its depth and direction
  void Add(const Eigen::Vector3d& to_neighbour, double depth, const Eigen::Vector3d& direction) {
    const double distance_sq = to_neighbour.squaredNorm();
    if (distance_sq < coincident_sq_) {
      if (!copied_) {
        copied_ = true;
        copied_depth_ = depth;
        copied_direction_ = direction;
      }
      return;
    }
    const double mu = 1.0 / distance_sq;
    weight_sum_ += mu;
    depth_sum_ += mu * (to_neighbour.dot(direction) + depth);
    direction_sum_ += mu * direction;
  }
  // false, leaving depth and direction as they were, where p gets no value:
  // no neighbour added, or their directions cancel
  bool Result(double& depth, Eigen::Vector3d& direction) const {
    if (copied_) {
      depth = copied_depth_;
      direction = copied_direction_;
      return true;
    }
    if (!(weight_sum_ > 0.0)) return false;
    const double length = direction_sum_.norm();
    if (!(length > kCancelledNormal * weight_sum_)) return false;
    depth = std::max(0.0, depth_sum_ / weight_sum_);
    direction = direction_sum_ / length;
    return true;
  }

 private:
  double coincident_sq_;
  double weight_sum_ = 0.0;
  double depth_sum_ = 0.0;
  Eigen::Vector3d direction_sum_ = Eigen::Vector3d::Zero();
  bool copied_ = false;
  double copied_depth_ = 0.0;
  Eigen::Vector3d copied_direction_ = Eigen::Vector3d::Zero();
};

// The squared distance from p to the box [lo, hi] (0 inside it).
[[gnu::always_inline]] inline double BoxDistance2(const Eigen::Vector3d& lo,
                                                  const Eigen::Vector3d& hi,
                                                  const Eigen::Vector3d& p) {
  // (Eigen's (lo - p).cwiseMax(p - hi).cwiseMax(0).squaredNorm(), the same
  // operations in the same order, written out and always inlined: once
  // the solver's code grew, g++ stopped inlining Eigen's into the box tree's
  // searches, and closest features took 10% more instructions; with SSE2,
  // x and y side by side, as Eigen did: written out one by one, 6% more)
#if defined(__SSE2__)
  const __m128d lo_xy = _mm_loadu_pd(lo.data()), hi_xy = _mm_loadu_pd(hi.data());
  const __m128d p_xy = _mm_loadu_pd(p.data());
  const __m128d d_xy =
      _mm_max_pd(_mm_max_pd(_mm_sub_pd(lo_xy, p_xy), _mm_sub_pd(p_xy, hi_xy)), _mm_setzero_pd());
  const __m128d d2_xy = _mm_mul_pd(d_xy, d_xy);
  const double d_z = std::max(std::max(lo[2] - p[2], p[2] - hi[2]), 0.0);
  return (_mm_cvtsd_f64(d2_xy) + _mm_cvtsd_f64(_mm_unpackhi_pd(d2_xy, d2_xy))) + d_z * d_z;
#else
  double d[3];
  for (int k = 0; k < 3; ++k) d[k] = std::max(std::max(lo[k] - p[k], p[k] - hi[k]), 0.0);
  return (d[0] * d[0] + d[1] * d[1]) + d[2] * d[2];
#endif
}

// The point of the triangle (a, b, c) nearest to p (exact, by Voronoi regions
// of the triangle's vertices, edges and face).
Eigen::Vector3d ClosestPointOnTriangle(const Eigen::Vector3d& p, const Eigen::Vector3d& a,
                                       const Eigen::Vector3d& b, const Eigen::Vector3d& c);

}  // namespace tetcosim
