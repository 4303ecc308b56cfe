#pragma once

// UTF-8 validation, for text that ends up in JSON (which must be UTF-8) and
// in messages: scene files and the names they give.

#include <cstddef>
#include <optional>
#include <string_view>

namespace tetcosim {

// The offset of the first byte of `text` that does not begin or continue a
// well-formed UTF-8 sequence (Unicode 15, table 3-7: no overlong forms, no
// surrogates U+D800..U+DFFF, nothing above U+10FFFF), or nothing if all of
// `text` is UTF-8. For a sequence cut short, the offset of its lead byte.
inline std::optional<size_t> FirstNonUtf8Byte(std::string_view text) {
  size_t i = 0;
  const size_t n = text.size();
  auto byte = [&](size_t k) { return static_cast<unsigned char>(text[k]); };
  auto in = [&](size_t k, unsigned char low, unsigned char high) {
    return k < n && byte(k) >= low && byte(k) <= high;
  };
  while (i < n) {
    const unsigned char lead = byte(i);
    size_t length = 0;
    if (lead <= 0x7F) {
      length = 1;
    } else if (lead >= 0xC2 && lead <= 0xDF) {
      length = in(i + 1, 0x80, 0xBF) ? 2 : 0;
    } else if (lead >= 0xE0 && lead <= 0xEF) {
      // second byte: A0..BF after E0 (not overlong), 80..9F after ED (not
      // a surrogate)
      const unsigned char low = lead == 0xE0 ? 0xA0 : 0x80;
      const unsigned char high = lead == 0xED ? 0x9F : 0xBF;
      length = in(i + 1, low, high) && in(i + 2, 0x80, 0xBF) ? 3 : 0;
    } else if (lead >= 0xF0 && lead <= 0xF4) {
      // second byte: 90..BF after F0 (not overlong), 80..8F after F4 (not
      // above U+10FFFF)
      const unsigned char low = lead == 0xF0 ? 0x90 : 0x80;
      const unsigned char high = lead == 0xF4 ? 0x8F : 0xBF;
      length = in(i + 1, low, high) && in(i + 2, 0x80, 0xBF) && in(i + 3, 0x80, 0xBF) ? 4 : 0;
    }
    if (length == 0) return i;
    i += length;
  }
  return std::nullopt;
}

}  // namespace tetcosim
