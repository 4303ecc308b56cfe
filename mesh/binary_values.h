#pragma once

// Numbers stored as bytes in binary mesh files (legacy and XML VTK): a value
// of 1, 2, 4 or 8 bytes in either byte order, signed, unsigned or
// floating-point. Internal to the mesh readers.

#include <cstdint>
#include <cstring>
#include <limits>
#include <span>
#include <string_view>

namespace tetcosim {

enum class ValueKind { kSigned, kUnsigned, kFloat };

// A value type of a file format: its name there, its size in bytes, its kind.
struct BinaryType {
  std::string_view name;
  int size;
  ValueKind kind;
};

// The entry of `types` named `name`, or nullptr.
inline const BinaryType* FindBinaryType(std::span<const BinaryType> types, std::string_view name) {
  for (const BinaryType& type : types) {
    if (type.name == name) return &type;
  }
  return nullptr;
}

// The `size` bytes (at most 8) at `bytes`, in the given byte order, as an
// unsigned integer.
inline std::uint64_t BytesToBits(const char* bytes, int size, bool big_endian) {
  std::uint64_t bits = 0;
  for (int i = 0; i < size; ++i) {
    const int shift = 8 * (big_endian ? size - 1 - i : i);
    bits |= static_cast<std::uint64_t>(static_cast<unsigned char>(bytes[i])) << shift;
  }
  return bits;
}

// A whole number of `size` bytes from its bits: a signed one sign-extended,
// an unsigned one past the largest long -1 (a count or index no mesh has).
// Not for kFloat.
inline long BitsToLong(std::uint64_t bits, int size, ValueKind kind) {
  if (kind == ValueKind::kUnsigned) {
    return bits > static_cast<std::uint64_t>(std::numeric_limits<long>::max())
               ? -1
               : static_cast<long>(bits);
  }
  const int unused = 64 - 8 * size;
  return static_cast<long>(static_cast<std::int64_t>(bits << unused) >> unused);
}

// Any value of `size` bytes from its bits, as a double (a float of 4 or 8
// bytes; a whole number converted as it is, however large).
inline double BitsToDouble(std::uint64_t bits, int size, ValueKind kind) {
  if (kind == ValueKind::kUnsigned) return static_cast<double>(bits);
  if (kind == ValueKind::kSigned) {
    const int unused = 64 - 8 * size;
    return static_cast<double>(static_cast<std::int64_t>(bits << unused) >> unused);
  }
  if (size == 4) {
    float value;
    const auto word = static_cast<std::uint32_t>(bits);
    std::memcpy(&value, &word, sizeof(value));
    return value;
  }
  double value;
  std::memcpy(&value, &bits, sizeof(value));
  return value;
}

}  // namespace tetcosim
