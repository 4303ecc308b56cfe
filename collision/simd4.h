#pragma once

// Four doubles at a time, for the penetration solver's inner loops (internal
// to collision/: included by its .cc files only).

#if defined(__AVX__)
#include <immintrin.h>
#endif

#include <Eigen/Core>
#include <algorithm>
#include <bit>
#include <cstdint>
#include <cstring>
#include <limits>
#include <vector>

namespace tetcosim {

// Four doubles in one SIMD register (AVX with x86-64-v3, two SSE2 registers
// with the baseline), through the compiler's vector extension; a comparison
// gives lanes of all ones (true) or zeros.
using Double4 = double __attribute__((vector_size(4 * sizeof(double))));
using Mask4 = std::int64_t __attribute__((vector_size(4 * sizeof(double))));

// Arrays read four entries at a time have this many more entries (NaN),
// so that a read from any entry stays inside them.
constexpr int kSimdPadding = 3;

// Sizes values to n entries and the padding, which it sets to NaN.
inline void ResizePadded(std::vector<double>& values, int n) {
  values.resize(n + kSimdPadding);
  std::fill(values.begin() + n, values.end(), std::numeric_limits<double>::quiet_NaN());
}

// Lane i holds i: lanes e + i at or past an end are masked off with it.
constexpr Mask4 kLanes = {0, 1, 2, 3};

inline Double4 Load4(const double* p) {
  Double4 v;
  std::memcpy(&v, p, sizeof v);
  return v;
}

// Bit i set: lane i of the mask is true (one instruction with AVX: the
// lanes' sign bits; the general expression takes about ten).
inline unsigned Bits(const Mask4& mask) {
#if defined(__AVX__)
  return static_cast<unsigned>(_mm256_movemask_pd(reinterpret_cast<__m256d>(mask)));
#else
  return static_cast<unsigned>((mask[0] & 1) | (mask[1] & 2) | (mask[2] & 4) | (mask[3] & 8));
#endif
}

// An axis-aligned box that tests four points at a time (stage 1: about 20
// candidate vertices per tetrahedron, one of them in its box).
class Box4 {
 public:
  Box4(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi)
      : lo_x_(Double4{} + lo.x()),
        lo_y_(Double4{} + lo.y()),
        lo_z_(Double4{} + lo.z()),
        hi_x_(Double4{} + hi.x()),
        hi_y_(Double4{} + hi.y()),
        hi_z_(Double4{} + hi.z()) {}

  // Bit j set: box i + j (< end) of the boxes [lo[k][i], hi[k][i]] (k:
  // the axis) overlaps this one (reads four boxes from i).
  unsigned Overlapping(const std::vector<double> (&lo)[3], const std::vector<double> (&hi)[3],
                       int i, int end) const {
    return Bits((Load4(&lo[0][i]) <= hi_x_) & (lo_x_ <= Load4(&hi[0][i])) &
                (Load4(&lo[1][i]) <= hi_y_) & (lo_y_ <= Load4(&hi[1][i])) &
                (Load4(&lo[2][i]) <= hi_z_) & (lo_z_ <= Load4(&hi[2][i])) & (kLanes + i < end));
  }

  // Bit j set: box j of four boxes [lo[k][j], hi[k][j]] overlaps this one.
  unsigned Overlapping(const double (&lo)[3][4], const double (&hi)[3][4]) const {
    return Bits((Load4(lo[0]) <= hi_x_) & (lo_x_ <= Load4(hi[0])) & (Load4(lo[1]) <= hi_y_) &
                (lo_y_ <= Load4(hi[1])) & (Load4(lo[2]) <= hi_z_) & (lo_z_ <= Load4(hi[2])));
  }

  // visit(e), in increasing order, for every entry e in [begin, end) of
  // points whose position lies in the box (lo <= p <= hi in every
  // coordinate; NaN is outside), four entries at a time (reading up to
  // three entries beyond end: the arrays' padding)
  template <typename Points, typename Visit>
  void ForEachInside(const Points& points, int begin, int end, Visit&& visit) const {
    for (int e = begin; e < end; e += 4) {
      const Double4 x = Load4(&points.x[e]), y = Load4(&points.y[e]), z = Load4(&points.z[e]);
      const Mask4 inside = (x >= lo_x_) & (x <= hi_x_) & (y >= lo_y_) & (y <= hi_y_) &
                           (z >= lo_z_) & (z <= hi_z_) & (kLanes + e < end);
      for (unsigned bits = Bits(inside); bits != 0; bits &= bits - 1) {
        visit(e + std::countr_zero(bits));
      }
    }
  }

 private:
  Double4 lo_x_, lo_y_, lo_z_, hi_x_, hi_y_, hi_z_;
};

// Lane j of four vectors by coordinate (values[k][j]: coordinate k of
// vector j), as a vector.
inline Eigen::Vector3d Lane(const double (&values)[3][4], int j) {
  return {values[0][j], values[1][j], values[2][j]};
}

}  // namespace tetcosim
