#include "mesh/xml_error.h"

#include <string_view>

namespace tetcosim {
namespace {

// What a tinyxml2 parse error means, in words.
const char* XmlErrorInWords(tinyxml2::XMLError error) {
  switch (error) {
    case tinyxml2::XML_ERROR_EMPTY_DOCUMENT:
      return "the file holds no element";
    case tinyxml2::XML_ERROR_PARSING_ELEMENT:
      return "a tag is malformed";
    case tinyxml2::XML_ERROR_PARSING_ATTRIBUTE:
      return "an attribute is malformed (each is name=\"value\", names unique in a tag)";
    case tinyxml2::XML_ERROR_PARSING_TEXT:
      return "text between tags is malformed";
    case tinyxml2::XML_ERROR_PARSING_CDATA:
      return "a CDATA section is not closed";
    case tinyxml2::XML_ERROR_PARSING_COMMENT:
      return "a comment is not closed with -->";
    case tinyxml2::XML_ERROR_PARSING_DECLARATION:
      return "the <?xml ...?> line is malformed";
    case tinyxml2::XML_ERROR_PARSING_UNKNOWN:
      return "a <!...> tag is malformed";
    case tinyxml2::XML_ERROR_MISMATCHED_ELEMENT:
      return "a closing tag does not match the element it closes";
    case tinyxml2::XML_ERROR_PARSING:
      return "an element is not closed, or something follows the last one";
    case tinyxml2::XML_ELEMENT_DEPTH_EXCEEDED:
      return "elements are nested too deeply";
    default:
      return "cannot read it as XML";
  }
}

}  // namespace

// The parse error in words, and where, when tinyxml2 tells more than the
// line (what follows its "Line number=N": the element, as "XMLElement
// name=worldbody").
std::string DescribeXmlError(const tinyxml2::XMLDocument& document) {
  std::string words = XmlErrorInWords(document.ErrorID());
  const std::string_view full = document.ErrorStr();
  const std::size_t line = full.find("Line number=");
  const std::size_t detail = line == full.npos ? line : full.find(": ", line);
  if (detail == full.npos) return words;
  constexpr std::string_view kElement = "XMLElement name=";
  const std::string_view where = full.substr(detail + 2);
  words += " (in ";
  if (where.starts_with(kElement)) {
    words += '<';
    words += where.substr(kElement.size());
    words += '>';
  } else {
    words += where;
  }
  words += ')';
  return words;
}

}  // namespace tetcosim
