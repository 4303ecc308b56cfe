#pragma once

// What a tinyxml2 parse error means, in words, for the errors of the readers
// of XML files (scenes, .vtu meshes).

#include <tinyxml2.h>

#include <string>

namespace tetcosim {

// The parse error of `document` in words, and where when tinyxml2 tells more
// than the line: "a closing tag does not match the element it closes (in
// <worldbody>)". The line itself is document.ErrorLineNum().
std::string DescribeXmlError(const tinyxml2::XMLDocument& document);

}  // namespace tetcosim
