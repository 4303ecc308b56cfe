#include "mesh/utf8.h"

#include <gtest/gtest.h>

#include <string>

namespace tetcosim {
namespace {

// code point -> UTF-8, as Unicode's table 3-6 lays the bits out
std::string Encode(char32_t c) {
  std::string s;
  auto put = [&](unsigned value) { s.push_back(static_cast<char>(value)); };
  if (c < 0x80) {
    put(c);
  } else if (c < 0x800) {
    put(0xC0 | (c >> 6));
    put(0x80 | (c & 0x3F));
  } else if (c < 0x10000) {
    put(0xE0 | (c >> 12));
    put(0x80 | ((c >> 6) & 0x3F));
    put(0x80 | (c & 0x3F));
  } else {
    put(0xF0 | (c >> 18));
    put(0x80 | ((c >> 12) & 0x3F));
    put(0x80 | ((c >> 6) & 0x3F));
    put(0x80 | (c & 0x3F));
  }
  return s;
}

TEST(Utf8, EveryScalarValueEncodedIsUtf8) {
  for (char32_t c = 0; c <= 0x10FFFF; ++c) {
    if (c >= 0xD800 && c <= 0xDFFF) continue;
    std::string text = "a";
    text += Encode(c);
    text += "b";
    ASSERT_EQ(FirstNonUtf8Byte(text), std::nullopt) << "U+" << std::hex << static_cast<unsigned>(c);
  }
  EXPECT_EQ(FirstNonUtf8Byte(""), std::nullopt);
}

// Every two-byte string is judged as the rule for its first byte says: a
// lead of C2..DF wants one continuation byte; ASCII is whole; the rest
// cannot end a sequence after one more byte.
TEST(Utf8, EveryTwoByteStringAgreesWithTheEncoder) {
  for (unsigned first = 0; first < 256; ++first) {
    for (unsigned second = 0; second < 256; ++second) {
      const std::string text{static_cast<char>(first), static_cast<char>(second)};
      std::optional<size_t> expected;
      if (first < 0x80) {
        expected = second < 0x80 ? std::nullopt : std::optional<size_t>(1);
      } else {
        // a valid two-byte string starting here is the encoding of some
        // U+0080..U+07FF: decode and compare
        const char32_t c = ((first & 0x1F) << 6) | (second & 0x3F);
        const bool valid = first >= 0xC0 && first < 0xE0 && (second & 0xC0) == 0x80 && c >= 0x80 &&
                           Encode(c) == text;
        expected = valid ? std::nullopt : std::optional<size_t>(0);
      }
      ASSERT_EQ(FirstNonUtf8Byte(text), expected) << std::hex << first << " " << second;
    }
  }
}

TEST(Utf8, MalformedSequencesAreFoundAtTheirLeadByte) {
  const struct {
    std::string text;
    size_t at;
  } cases[] = {
      {"ab\x80", 2},             // a continuation byte alone
      {"a\xC0\x80", 1},          // U+0000 overlong in two bytes
      {"a\xC1\xBF", 1},          // U+007F overlong
      {"a\xE0\x80\x80", 1},      // overlong in three bytes
      {"a\xE0\x9F\xBF", 1},      // U+07FF overlong
      {"a\xED\xA0\x80", 1},      // U+D800, a surrogate
      {"a\xED\xBF\xBF", 1},      // U+DFFF
      {"a\xF0\x8F\xBF\xBF", 1},  // U+FFFF overlong in four bytes
      {"a\xF4\x90\x80\x80", 1},  // U+110000
      {"a\xF5\x80\x80\x80", 1},  // F5..FF never appear
      {"a\xFF", 1},
      {"abc\xE2\x82", 3},               // cut short
      {"abc\xF0\x9F\x98", 3},           // cut short
      {"\xC3\xA9t\xC3\xA9\xC3", 5},     // "été" and a lead byte at the end
      {"\xE2\x82\xAC\xE2\x28\xA1", 3},  // a bad second byte
  };
  for (const auto& c : cases) {
    EXPECT_EQ(FirstNonUtf8Byte(c.text), std::optional<size_t>(c.at)) << c.text;
  }
}

}  // namespace
}  // namespace tetcosim
