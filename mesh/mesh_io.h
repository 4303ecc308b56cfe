#pragma once

// Reading and writing tetrahedral meshes.
//
// Readers (all return an unvalidated RawMesh; TetMesh::Build validates):
//   Gmsh MSH 2.2 and 4.1, ASCII and binary (.msh)
//   TetGen .node + .ele, 0- or 1-based, with attributes and boundary markers
//   legacy VTK unstructured grid, ASCII or BINARY, versions 2 to 5.1 (.vtk;
//   cell type 10)
//   VTK XML unstructured grid (.vtu; cell type 10): ascii, binary and appended
//   (raw or base64) arrays, UInt32 or UInt64 headers, either byte order,
//   uncompressed or zlib-compressed (vtkZLibDataCompressor)
// Writers:
//   VTK XML unstructured grid (.vtu) and legacy VTK (.vtk), ASCII, with
//   optional per-point and per-cell data arrays; readable by ParaView and
//   meshio. Files are written to a temporary name and renamed, so a reader
//   never sees half a file.

#include <string>
#include <string_view>
#include <vector>

#include "mesh/tet_mesh.h"

namespace tetcosim {

enum class MeshFormat { kGmsh, kTetGen, kVtkLegacy, kVtkXml };

// Reads any supported format, chosen by extension (.msh, .node/.ele, .vtk, .vtu)
// or, failing that, by the file's first bytes. Throws Error for a missing,
// unreadable, truncated or malformed file, naming the file and line.
RawMesh ReadRawMesh(const std::string& path);

// ReadRawMesh, then TetMesh::Build.
TetMesh ReadTetMesh(const std::string& path, const TetMeshOptions& options = {});

// A mesh from a file name or a generator spec such as "sphere:size=0.1:res=1"
// (see generators.h).
TetMesh LoadMesh(const std::string& file_or_spec, const TetMeshOptions& options = {});

// The individual readers, on content already in memory (path is for messages).
RawMesh ReadGmsh(const std::string& path, std::string_view content);
RawMesh ReadVtkLegacy(const std::string& path, std::string_view content);
RawMesh ReadVtu(const std::string& path, std::string_view content);
// node_path and ele_path name the two TetGen files.
RawMesh ReadTetGen(const std::string& node_path, std::string_view node_content,
                   const std::string& ele_path, std::string_view ele_content);

// A named data array: `components` values per point or per cell, flattened.
struct DataArray {
  std::string name;
  int components = 1;
  std::vector<double> values;  // #points (or #cells) * components
};

struct VtkData {
  std::vector<DataArray> point_data;
  std::vector<DataArray> cell_data;
};

// Writes positions (#V x 3) and tets (#T x 4) as an unstructured grid of
// cell type 10 (VTK_TETRA). .vtu for XML, anything else legacy. Throws Error
// if the file cannot be written or an array has the wrong size.
void WriteVtk(const std::string& path, const Positions& positions, const Tets& tets,
              const VtkData& data = {});

// The readers' warning for `count` higher-order tetrahedra (10 nodes and
// more) read as linear ones, from their corner nodes.
std::string LinearizedTetsWarning(long count);

// The nodes of a VTK cell type that is a tetrahedron, 0 for any other type:
// 4 for VTK_TETRA (10), 10 for VTK_QUADRATIC_TETRA (24; its corners first).
constexpr int VtkTetNodes(long cell_type) {
  return cell_type == 10 ? 4 : cell_type == 24 ? 10 : 0;
}

// Writes content to path through a temporary file and a rename.
void WriteFileAtomically(const std::string& path, std::string_view content);

}  // namespace tetcosim
