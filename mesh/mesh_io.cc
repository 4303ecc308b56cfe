#include "mesh/mesh_io.h"

#include <filesystem>

#include "mesh/error.h"
#include "mesh/generators.h"
#include "mesh/text_reader.h"

namespace tetcosim {
namespace {

std::string Extension(const std::string& path) {
  std::string ext = std::filesystem::path(path).extension().string();
  for (char& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return ext;
}

RawMesh ReadTetGenPair(const std::string& path) {
  std::filesystem::path base(path);
  std::string ext = Extension(path);
  if (ext == ".node" || ext == ".ele") base.replace_extension();
  std::string node_path = base.string() + ".node";
  std::string ele_path = base.string() + ".ele";
  std::string node_content = ReadFileContents(node_path);
  std::string ele_content = ReadFileContents(ele_path);
  return ReadTetGen(node_path, node_content, ele_path, ele_content);
}

}  // namespace

RawMesh ReadRawMesh(const std::string& path) {
  std::string ext = Extension(path);
  if (ext == ".node" || ext == ".ele") return ReadTetGenPair(path);
  if (ext.empty() && !std::filesystem::exists(path) && std::filesystem::exists(path + ".node")) {
    return ReadTetGenPair(path);
  }
  std::string content = ReadFileContents(path);
  if (ext == ".msh" || content.rfind("$MeshFormat", 0) == 0) return ReadGmsh(path, content);
  if (ext == ".vtk" || content.rfind("# vtk DataFile", 0) == 0) return ReadVtkLegacy(path, content);
  if (ext == ".vtu" || content.rfind("<VTKFile", 0) == 0 ||
      (content.rfind("<?xml", 0) == 0 && content.substr(0, 200).find("<VTKFile") != content.npos)) {
    return ReadVtu(path, content);
  }
  ThrowAt(path, 0,
          "unknown mesh format '" + ext +
              "'; tetcosim reads Gmsh .msh (2.2, 4.1), "
              "TetGen .node/.ele, legacy .vtk and VTK XML .vtu");
}

std::string LinearizedTetsWarning(long count) {
  return std::to_string(count) +
         " higher-order tetrahedra were read as linear ones: their 4 corner nodes are kept and "
         "the others left out (tetcosim's elements are linear; mesh with element order 1 to "
         "keep the nodes)";
}

TetMesh ReadTetMesh(const std::string& path, const TetMeshOptions& options) {
  return TetMesh::Build(ReadRawMesh(path), options);
}

TetMesh LoadMesh(const std::string& file_or_spec, const TetMeshOptions& options) {
  if (IsShapeSpec(file_or_spec)) return TetMesh::Build(MakeShape(file_or_spec), options);
  return ReadTetMesh(file_or_spec, options);
}

}  // namespace tetcosim
