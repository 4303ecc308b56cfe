// Legacy VTK (ASCII or BINARY, "# vtk DataFile Version 2.0" to "5.1") reading and
// VTK writing (XML .vtu or legacy), reference: "VTK File Formats" in the VTK
// User's Guide. Only tetrahedra are kept on reading: cell type 10 (VTK_TETRA),
// and 24 (VTK_QUADRATIC_TETRA) from its corners.

#include <algorithm>
#include <array>
#include <charconv>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>

#include "mesh/binary_values.h"
#include "mesh/error.h"
#include "mesh/mesh_io.h"
#include "mesh/text_reader.h"

namespace tetcosim {
namespace {

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

// The values of a legacy VTK array: text tokens in an ASCII file; in a
// BINARY one, big-endian values of the array's type, from just after the
// newline of the line that names the array.
class LegacyValues {
 public:
  LegacyValues(Scanner& scan, bool binary) : scan_(scan), binary_(binary) {
    // (errors in a binary file give the byte: its lines are not counted)
    scan.set_binary(binary);
  }

  bool binary() const { return binary_; }

  // Begins an array of `count` values of `type`: in a binary file, checks
  // the type and that the bytes are there, and moves to them.
  void Begin(std::string_view type, long count, std::string_view what) {
    if (!binary_) return;
    const BinaryType* found = FindBinaryType(kTypes, type);
    if (!found) {
      scan_.Fail("the data type '" + std::string(type.substr(0, 40)) + "' of the " +
                 std::string(what) +
                 " cannot be read from a binary file; tetcosim reads char, short, int, long, "
                 "float, double and vtktypeint64 (signed or unsigned); save the file as ASCII "
                 "or .vtu");
    }
    size_ = found->size;
    kind_ = found->kind;
    scan_.SkipLine();
    scan_.CheckCount(count, static_cast<size_t>(size_), what);
  }

  // Passes over an array (of a FIELD).
  void Skip(std::string_view type, long count, std::string_view what) {
    if (!binary_) {
      for (long i = 0; i < count; ++i) scan_.Token("a field value");
      return;
    }
    Begin(type, count, what);
    scan_.SkipBytes(static_cast<size_t>(count) * static_cast<size_t>(size_));
  }

  long Int(std::string_view what) {
    if (!binary_) return scan_.Int(what);
    if (kind_ == ValueKind::kFloat) {
      scan_.Fail("expected " + std::string(what) +
                 ", an integer, but the array holds floating-point values");
    }
    return BitsToLong(NextBits(what), size_, kind_);
  }

  double Double(std::string_view what) {
    if (!binary_) return scan_.Double(what);
    return BitsToDouble(NextBits(what), size_, kind_);
  }

  // The line of the next value (0 in a binary file, whose errors give the byte).
  long line() const { return binary_ ? 0 : scan_.line(); }

 private:
  static constexpr std::array<BinaryType, 14> kTypes = {
      {{"char", 1, ValueKind::kSigned},
       {"unsigned_char", 1, ValueKind::kUnsigned},
       {"short", 2, ValueKind::kSigned},
       {"unsigned_short", 2, ValueKind::kUnsigned},
       {"int", 4, ValueKind::kSigned},
       {"unsigned_int", 4, ValueKind::kUnsigned},
       {"long", 8, ValueKind::kSigned},
       {"unsigned_long", 8, ValueKind::kUnsigned},
       {"vtktypeint32", 4, ValueKind::kSigned},
       {"vtktypeuint32", 4, ValueKind::kUnsigned},
       {"vtktypeint64", 8, ValueKind::kSigned},
       {"vtktypeuint64", 8, ValueKind::kUnsigned},
       {"float", 4, ValueKind::kFloat},
       {"double", 8, ValueKind::kFloat}}};

  // the next value's bytes (big-endian, as legacy VTK writes them)
  std::uint64_t NextBits(std::string_view what) {
    scan_.RequireBytes(static_cast<size_t>(size_), what);
    char bytes[8];
    for (int i = 0; i < size_; ++i) bytes[i] = scan_.Binary<char>(what);
    return BytesToBits(bytes, size_, /*big_endian=*/true);
  }

  Scanner& scan_;
  bool binary_;
  int size_ = 0;
  ValueKind kind_ = ValueKind::kSigned;
};

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
  constexpr std::string_view kMagic = "# vtk DataFile Version";
  if (header.rfind(kMagic, 0) != 0) {
    scan.Fail("not a legacy VTK file: the first line must be '# vtk DataFile Version x.y'");
  }
  // (5.1 lists cells as OFFSETS and CONNECTIVITY; a binary file must say so
  // by its version, as its cell list cannot be looked at as text)
  const bool version5 = header.find(" 5.", kMagic.size()) != std::string_view::npos;
  scan.SkipLine();
  scan.SkipLine();  // title
  std::string_view encoding = scan.Token("ASCII or BINARY");
  if (encoding != "ASCII" && encoding != "BINARY") {
    scan.Fail("expected ASCII or BINARY, found '" + std::string(encoding.substr(0, 40)) + "'");
  }
  LegacyValues values(scan, encoding == "BINARY");
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
      scan.CheckCount(n, values.binary() ? 12 : 6, "points");
      values.Begin(scan.Token("the point data type"), 3 * n, "point coordinates");
      raw.positions.resize(n, 3);
      raw.node_lines.resize(static_cast<size_t>(n));
      for (long v = 0; v < n; ++v) {
        for (int k = 0; k < 3; ++k) {
          if (k == 0) raw.node_lines[static_cast<size_t>(v)] = values.line();
          raw.positions(v, k) = values.Double("a point coordinate");
        }
      }
      have_points = true;
    } else if (keyword == "CELLS") {
      long n = scan.Int("the number of cells");
      long size = scan.Int("the cell list size");
      scan.CheckCount(n, 2, "cells");
      scan.CheckCount(size, 2, "cell list entries");
      offsets.assign(1, 0);
      // (ASCII: told by the first word)
      const bool offsets_form =
          values.binary() ? version5 : scan.PeekToken("the cell list") == "OFFSETS";
      if (offsets_form) {
        // version 5.1: OFFSETS <type> n values, CONNECTIVITY <type> size values
        scan.Expect("OFFSETS");
        values.Begin(scan.Token("the offsets data type"), n, "offsets");
        offsets.clear();
        for (long i = 0; i < n; ++i) offsets.push_back(values.Int("an offset"));
        scan.Expect("CONNECTIVITY");
        values.Begin(scan.Token("the connectivity data type"), size, "connectivity");
        for (long i = 0; i < size; ++i) connectivity.push_back(values.Int("a cell vertex"));
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
        // versions 2 to 4.2: n lines "k i0 ... ik-1" (binary: int, as VTK writes them)
        values.Begin("int", size, "the cell list");
        long listed = 0;  // entries read, counts included
        for (long c = 0; c < n; ++c) {
          const long count = values.Int("a cell vertex count");
          if (count < 0 || count > size - listed - 1) {
            scan.Fail("cell " + std::to_string(c) + " has a vertex count of " +
                      std::to_string(count) + ", outside 0 to the " +
                      std::to_string(std::max(0L, size - listed - 1)) + " entries the CELLS size " +
                      std::to_string(size) +
                      " leaves it; a tetrahedron's line is 4 and its 4 point indices");
          }
          cell_lines.push_back(values.line());
          for (long k = 0; k < count; ++k) connectivity.push_back(values.Int("a cell vertex"));
          listed += count + 1;
          offsets.push_back(static_cast<long>(connectivity.size()));
        }
        if (listed != size) {
          scan.Fail("the CELLS size " + std::to_string(size) + " does not match the cell list");
        }
      }
      have_cells = true;
    } else if (keyword == "CELL_TYPES") {
      long n = scan.Int("the number of cell types");
      scan.CheckCount(n, 2, "cell types");
      values.Begin("int", n, "the cell types");
      for (long i = 0; i < n; ++i) types.push_back(values.Int("a cell type"));
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
        scan.CheckCount(components * tuples, values.binary() ? 1 : 2, "field values");
        values.Skip(scan.Token("the array data type"), components * tuples, "field values");
      }
    } else if (keyword == "METADATA") {
      // lines up to the first blank one (AtEnd() would pass over the blank
      // line, and take the next section for more metadata)
      scan.SkipLine();
      while (!scan.TokenOnLine().empty()) scan.SkipLine();
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
  long num_linearized = 0;  // quadratic tetrahedra, read from their corners
  for (long c = 0; c < num_cells; ++c) {
    const long type = types[static_cast<size_t>(c)];
    const int nodes = VtkTetNodes(type);
    if (nodes == 0) continue;
    long begin = offsets[static_cast<size_t>(c)];
    if (offsets[static_cast<size_t>(c) + 1] - begin != nodes) {
      ThrowAt(path, cell_lines[static_cast<size_t>(c)],
              "cell " + std::to_string(c) + " has type " + std::to_string(type) +
                  " (a tetrahedron of " + std::to_string(nodes) + " points) but " +
                  std::to_string(offsets[static_cast<size_t>(c) + 1] - begin) + " points");
    }
    num_linearized += nodes != 4;
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
  if (num_linearized > 0) raw.warnings.push_back(LinearizedTetsWarning(num_linearized));
  return raw;
}

}  // namespace tetcosim
