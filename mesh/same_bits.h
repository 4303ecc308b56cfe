#pragma once

// Whether two arrays of doubles hold the same bits: unlike ==, +0 and -0
// differ and a NaN equals itself. For checks that nothing changed (a body
// that did not move, bit for bit) and for the tests of determinism, which
// mean the same bits, not equal values.

#include <bit>
#include <cstddef>
#include <cstdint>
#include <span>

namespace tetcosim {

inline bool SameBits(std::span<const double> a, std::span<const double> b) {
  if (a.size() != b.size()) return false;
  for (std::size_t i = 0; i < a.size(); ++i) {
    if (std::bit_cast<std::uint64_t>(a[i]) != std::bit_cast<std::uint64_t>(b[i])) return false;
  }
  return true;
}

}  // namespace tetcosim
