// Legacy VTK (ASCII, "# vtk DataFile Version 2.0" to "5.1") reading and
// VTK writing (XML .vtu or legacy), reference: "VTK File Formats" in the VTK
// User's Guide. Only cell type 10 (VTK_TETRA) is kept on reading.

#include <charconv>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>

#include "mesh/error.h"
#include "mesh/mesh_io.h"
#include "mesh/text_reader.h"

namespace tetcosim {
namespace {

constexpr int kVtkTetra = 10;

// appends a double in the shortest form that reads back to the same value
void AppendNumber(std::string& out, double value) {
  char buffer[32];
  auto result = std::to_chars(buffer, buffer + sizeof(buffer), value);
  out.append(buffer, result.ptr);
}
void AppendNumber(std::string& out, long value) {
  char buffer[24];
  auto result = std::to_chars(buffer, buffer + sizeof(buffer), value);
  out.append(buffer, result.ptr);
}

void CheckArray(const std::string& path, const DataArray& array, long count, const char* kind) {
  if (array.components < 1 || static_cast<long>(array.values.size()) != count * array.components) {
    ThrowAt(path, 0,
            std::string(kind) + " data array '" + array.name + "' has " +
                std::to_string(array.values.size()) + " values; expected " + std::to_string(count) +
                " x " + std::to_string(array.components));
  }
}

void AppendXmlArray(std::string& out, const DataArray& array) {
  out += "<DataArray type=\"Float64\" Name=\"" + array.name + "\" NumberOfComponents=\"" +
         std::to_string(array.components) + "\" format=\"ascii\">\n";
  for (size_t i = 0; i < array.values.size(); ++i) {
    AppendNumber(out, array.values[i]);
    out += (i + 1) % static_cast<size_t>(array.components) == 0 ? '\n' : ' ';
  }
  out += "</DataArray>\n";
}

std::string XmlVtu(const Positions& positions, const Tets& tets, const VtkData& data) {
  std::string out;
  out.reserve(static_cast<size_t>(positions.rows()) * 60 + static_cast<size_t>(tets.rows()) * 40);
  out += "<?xml version=\"1.0\"?>\n";
  out +=
      "<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" "
      "header_type=\"UInt64\">\n<UnstructuredGrid>\n";
  out += "<Piece NumberOfPoints=\"" + std::to_string(positions.rows()) + "\" NumberOfCells=\"" +
         std::to_string(tets.rows()) + "\">\n";
  out += "<PointData>\n";
  for (const DataArray& array : data.point_data) AppendXmlArray(out, array);
  out += "</PointData>\n<CellData>\n";
  for (const DataArray& array : data.cell_data) AppendXmlArray(out, array);
  out += "</CellData>\n<Points>\n";
  DataArray points{"Points", 3, {positions.data(), positions.data() + positions.size()}};
  AppendXmlArray(out, points);
  out += "</Points>\n<Cells>\n";
  out += "<DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n";
  for (Eigen::Index t = 0; t < tets.rows(); ++t) {
    for (int k = 0; k < 4; ++k) {
      AppendNumber(out, static_cast<long>(tets(t, k)));
      out += k == 3 ? '\n' : ' ';
    }
  }
  out += "</DataArray>\n<DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">\n";
  for (Eigen::Index t = 0; t < tets.rows(); ++t) {
    AppendNumber(out, static_cast<long>(4 * (t + 1)));
    out += '\n';
  }
  out += "</DataArray>\n<DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">\n";
  for (Eigen::Index t = 0; t < tets.rows(); ++t) out += "10\n";
  out += "</DataArray>\n</Cells>\n</Piece>\n</UnstructuredGrid>\n</VTKFile>\n";
  return out;
}

void AppendLegacyArray(std::string& out, const DataArray& array) {
  out += "SCALARS " + array.name + " double " + std::to_string(array.components) +
         "\nLOOKUP_TABLE default\n";
  for (size_t i = 0; i < array.values.size(); ++i) {
    AppendNumber(out, array.values[i]);
    out += (i + 1) % static_cast<size_t>(array.components) == 0 ? '\n' : ' ';
  }
}

std::string LegacyVtk(const Positions& positions, const Tets& tets, const VtkData& data) {
  std::string out = "# vtk DataFile Version 4.2\ntetcosim mesh\nASCII\nDATASET UNSTRUCTURED_GRID\n";
  out += "POINTS " + std::to_string(positions.rows()) + " double\n";
  for (Eigen::Index v = 0; v < positions.rows(); ++v) {
    for (int k = 0; k < 3; ++k) {
      AppendNumber(out, positions(v, k));
      out += k == 2 ? '\n' : ' ';
    }
  }
  out += "CELLS " + std::to_string(tets.rows()) + " " + std::to_string(5 * tets.rows()) + "\n";
  for (Eigen::Index t = 0; t < tets.rows(); ++t) {
    out += "4";
    for (int k = 0; k < 4; ++k) {
      out += ' ';
      AppendNumber(out, static_cast<long>(tets(t, k)));
    }
    out += '\n';
  }
  out += "CELL_TYPES " + std::to_string(tets.rows()) + "\n";
  for (Eigen::Index t = 0; t < tets.rows(); ++t) out += "10\n";
  if (!data.point_data.empty()) {
    out += "POINT_DATA " + std::to_string(positions.rows()) + "\n";
    for (const DataArray& array : data.point_data) AppendLegacyArray(out, array);
  }
  if (!data.cell_data.empty()) {
    out += "CELL_DATA " + std::to_string(tets.rows()) + "\n";
    for (const DataArray& array : data.cell_data) AppendLegacyArray(out, array);
  }
  return out;
}

}  // namespace

void WriteFileAtomically(const std::string& path, std::string_view content) {
  std::error_code error;
  if (path.empty()) throw Error("no file name to write to");
  if (path.back() == '/' || std::filesystem::is_directory(path, error)) {
    ThrowAt(path, 0, "is a folder; give the name of a file to write");
  }
  const std::string temporary = path + ".tmp";
  // (a failed write leaves neither the temporary file nor a partial one)
  auto fail = [&](const std::string& message) {
    std::filesystem::remove(temporary, error);
    ThrowAt(path, 0, message);
  };
  {
    std::ofstream out(temporary, std::ios::binary | std::ios::trunc);
    if (!out) ThrowAt(path, 0, "cannot write: check that the folder exists and is writable");
    out.write(content.data(), static_cast<std::streamsize>(content.size()));
    out.close();
    if (!out) fail("write failed (disk full?)");
  }
  std::filesystem::rename(temporary, path, error);
  if (error) fail("cannot rename the temporary file: " + error.message());
}

void WriteVtk(const std::string& path, const Positions& positions, const Tets& tets,
              const VtkData& data) {
  for (const DataArray& array : data.point_data) CheckArray(path, array, positions.rows(), "point");
  for (const DataArray& array : data.cell_data) CheckArray(path, array, tets.rows(), "cell");
  bool xml = path.size() >= 4 && path.compare(path.size() - 4, 4, ".vtu") == 0;
  WriteFileAtomically(path, xml ? XmlVtu(positions, tets, data) : LegacyVtk(positions, tets, data));
}

RawMesh ReadVtkLegacy(const std::string& path, std::string_view content) {
  RawMesh raw;
  raw.source = path;
  Scanner scan(path, content);
  // header: "# vtk DataFile Version x.y", a title line, ASCII|BINARY, DATASET
  size_t first_line_end = content.find('\n');
  std::string_view header = content.substr(0, first_line_end);
  if (header.rfind("# vtk DataFile Version", 0) != 0) {
    scan.Fail("not a legacy VTK file: the first line must be '# vtk DataFile Version x.y'");
  }
  scan.SkipLine();
  scan.SkipLine();  // title
  std::string_view encoding = scan.Token("ASCII or BINARY");
  if (encoding == "BINARY") {
    scan.Fail("binary legacy VTK is not supported; write it as ASCII or as .vtu");
  }
  if (encoding != "ASCII") scan.Fail("expected ASCII, found '" + std::string(encoding) + "'");
  scan.Expect("DATASET");
  std::string_view dataset = scan.Token("the dataset type");
  if (dataset != "UNSTRUCTURED_GRID") {
    scan.Fail("dataset " + std::string(dataset) +
              " is not supported; tetcosim reads "
              "UNSTRUCTURED_GRID with tetrahedra (cell type 10)");
  }

  std::vector<long> offsets;       // #cells + 1
  std::vector<long> connectivity;  // all cell vertex indices
  std::vector<long> cell_lines;
  std::vector<long> types;
  bool have_points = false;
  bool have_cells = false;
  while (!scan.AtEnd()) {
    std::string_view keyword = scan.Token("a section keyword");
    if (keyword == "POINTS") {
      long n = scan.Int("the number of points");
      scan.CheckCount(n, 6, "points");
      scan.Token("the point data type");
      raw.positions.resize(n, 3);
      raw.node_lines.resize(static_cast<size_t>(n));
      for (long v = 0; v < n; ++v) {
        for (int k = 0; k < 3; ++k) {
          if (k == 0) raw.node_lines[static_cast<size_t>(v)] = scan.line();
          raw.positions(v, k) = scan.Double("a point coordinate");
        }
      }
      have_points = true;
    } else if (keyword == "CELLS") {
      long n = scan.Int("the number of cells");
      long size = scan.Int("the cell list size");
      scan.CheckCount(n, 2, "cells");
      scan.CheckCount(size, 2, "cell list entries");
      offsets.assign(1, 0);
      std::string_view next = scan.Token("the cell list");
      if (next == "OFFSETS") {
        // version 5.1: OFFSETS <type> n values, CONNECTIVITY <type> size values
        scan.Token("the offsets data type");
        offsets.clear();
        for (long i = 0; i < n; ++i) offsets.push_back(scan.Int("an offset"));
        scan.Expect("CONNECTIVITY");
        scan.Token("the connectivity data type");
        for (long i = 0; i < size; ++i) connectivity.push_back(scan.Int("a cell vertex"));
        for (size_t i = 1; i < offsets.size(); ++i) {
          if (offsets[i] < offsets[i - 1] || offsets[i] > size) {
            scan.Fail("OFFSETS value " + std::to_string(i) + " (" + std::to_string(offsets[i]) +
                      ") is " +
                      (offsets[i] > size
                           ? "beyond the " + std::to_string(size) + " CONNECTIVITY entries"
                           : "below the one before it (" + std::to_string(offsets[i - 1]) + ")") +
                      "; offsets must rise from 0 to the connectivity size");
          }
        }
        if (!offsets.empty() && (offsets.front() != 0 || offsets.back() != size)) {
          scan.Fail("OFFSETS must start at 0 and end at the connectivity size");
        }
        cell_lines.assign(offsets.empty() ? 0 : offsets.size() - 1, 0);
      } else {
        // versions 2 to 4.2: n lines "k i0 ... ik-1"
        long count = -1;
        auto [end, ec] = std::from_chars(next.data(), next.data() + next.size(), count);
        if (ec != std::errc() || end != next.data() + next.size()) {
          scan.Fail("expected a cell vertex count, found '" + std::string(next.substr(0, 40)) +
                    "'");
        }
        for (long c = 0; c < n; ++c) {
          if (c > 0) count = scan.Int("a cell vertex count");
          if (count < 0 || count > size) {
            scan.Fail("cell " + std::to_string(c) + " has a vertex count of " +
                      std::to_string(count) + ", outside 0 to the CELLS size " +
                      std::to_string(size) + "; a tetrahedron's line is 4 and its 4 point indices");
          }
          cell_lines.push_back(scan.line());
          for (long k = 0; k < count; ++k) connectivity.push_back(scan.Int("a cell vertex"));
          offsets.push_back(static_cast<long>(connectivity.size()));
        }
        if (static_cast<long>(connectivity.size()) + n != size) {
          scan.Fail("the CELLS size " + std::to_string(size) + " does not match the cell list");
        }
      }
      have_cells = true;
    } else if (keyword == "CELL_TYPES") {
      long n = scan.Int("the number of cell types");
      scan.CheckCount(n, 2, "cell types");
      for (long i = 0; i < n; ++i) types.push_back(scan.Int("a cell type"));
    } else if (keyword == "POINT_DATA" || keyword == "CELL_DATA") {
      break;  // attributes follow; the mesh is complete
    } else if (keyword == "FIELD") {
      scan.Token("the field name");
      long arrays = scan.Int("the number of field arrays");
      for (long a = 0; a < arrays; ++a) {
        scan.Token("an array name");
        long components = scan.Int("the number of components");
        long tuples = scan.Int("the number of tuples");
        if (components < 0 || tuples < 0 ||
            (tuples > 0 && components > std::numeric_limits<long>::max() / tuples)) {
          scan.Fail("a FIELD array of " + std::to_string(components) + " components and " +
                    std::to_string(tuples) +
                    " tuples: each must be 0 or more, and their product a count of values; the "
                    "file is damaged");
        }
        scan.CheckCount(components * tuples, 2, "field values");
        scan.Token("the array data type");
        for (long i = 0; i < components * tuples; ++i) scan.Token("a field value");
      }
    } else if (keyword == "METADATA") {
      scan.SkipLine();
      while (!scan.AtEnd() && !scan.TokenOnLine().empty()) scan.SkipLine();
    } else {
      scan.Fail("unexpected keyword '" + std::string(keyword.substr(0, 40)) + "'");
    }
  }
  if (!have_points) scan.Fail("the file has no POINTS");
  if (!have_cells) scan.Fail("the file has no CELLS");
  long num_cells = static_cast<long>(offsets.size()) - 1;
  if (static_cast<long>(types.size()) != num_cells) {
    scan.Fail("CELL_TYPES lists " + std::to_string(types.size()) + " cells but CELLS has " +
              std::to_string(num_cells));
  }
  std::vector<int> tets;
  for (long c = 0; c < num_cells; ++c) {
    if (types[static_cast<size_t>(c)] != kVtkTetra) continue;
    long begin = offsets[static_cast<size_t>(c)];
    if (offsets[static_cast<size_t>(c) + 1] - begin != 4) {
      ThrowAt(path, cell_lines[static_cast<size_t>(c)],
              "cell " + std::to_string(c) + " has type 10 (tetrahedron) but not 4 vertices");
    }
    for (int k = 0; k < 4; ++k) {
      long v = connectivity[static_cast<size_t>(begin + k)];
      if (v < 0 || v >= raw.positions.rows()) {
        ThrowAt(path, cell_lines[static_cast<size_t>(c)],
                "cell " + std::to_string(c) + " refers to point " + std::to_string(v) +
                    ", outside the " + std::to_string(raw.positions.rows()) + " points");
      }
      tets.push_back(static_cast<int>(v));
    }
    raw.element_ids.push_back(c);
    raw.element_lines.push_back(cell_lines[static_cast<size_t>(c)]);
  }
  raw.tets = Eigen::Map<const Tets>(tets.data(), static_cast<Eigen::Index>(tets.size() / 4), 4);
  return raw;
}

}  // namespace tetcosim
