#pragma once

// Text written into XML that tetcosim makes (the skins it adds to a scene's
// MJCF, ParaView's .pvd index).

#include <string>
#include <string_view>

namespace tetcosim {

// `text` with XML's special characters escaped (& < > " '), for an
// attribute value in quotes or element text: a name given in a scene as
// "a &amp; b" reads as "a & b", and is written back as it was given.
inline std::string XmlEscaped(std::string_view text) {
  std::string escaped;
  escaped.reserve(text.size());
  for (const char c : text) {
    switch (c) {
      case '&':
        escaped += "&amp;";
        break;
      case '<':
        escaped += "&lt;";
        break;
      case '>':
        escaped += "&gt;";
        break;
      case '"':
        escaped += "&quot;";
        break;
      case '\'':
        escaped += "&apos;";
        break;
      default:
        escaped += c;
    }
  }
  return escaped;
}

}  // namespace tetcosim
