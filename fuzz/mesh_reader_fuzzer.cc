// libFuzzer target for the mesh readers and TetMesh validation. The first
// byte picks the reader; the rest is the file. Any tetcosim::Error is a
// correct answer to bad input; a crash, hang, leak or sanitizer report is a
// bug.

#include <cstddef>
#include <cstdint>
#include <string_view>

#include "mesh/error.h"
#include "mesh/mesh_io.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 1) return 0;
  std::string_view content(reinterpret_cast<const char*>(data + 1), size - 1);
  try {
    tetcosim::RawMesh raw;
    switch (data[0] % 4) {
      case 0:
        raw = tetcosim::ReadGmsh("fuzz.msh", content);
        break;
      case 1:
        raw = tetcosim::ReadVtkLegacy("fuzz.vtk", content);
        break;
      case 3:
        raw = tetcosim::ReadVtu("fuzz.vtu", content);
        break;
      default: {
        // .node and .ele separated by the first '@'
        size_t split = content.find('@');
        if (split == std::string_view::npos) return 0;
        raw = tetcosim::ReadTetGen("fuzz.node", content.substr(0, split), "fuzz.ele",
                                   content.substr(split + 1));
      }
    }
    tetcosim::TetMesh mesh = tetcosim::TetMesh::Build(std::move(raw));
  } catch (const tetcosim::Error&) {
  }
  return 0;
}
