// Every kind of bad input gets its own clear error: which file, which line
// or element, what is wrong.

#include <gtest/gtest.h>

#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <span>
#include <string_view>
#include <vector>

#include "mesh/error.h"
#include "mesh/mesh_io.h"
#include "mesh/text_reader.h"

namespace tetcosim {
namespace {

const std::string kData = TETCOSIM_TEST_DATA_DIR;

class BadInput : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = std::filesystem::temp_directory_path() /
           ("tetcosim_bad_input_" + std::to_string(::getpid()));
    std::filesystem::create_directories(dir_);
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }

  std::string Write(const std::string& name, const std::string& content) {
    std::string path = (dir_ / name).string();
    std::ofstream(path, std::ios::binary) << content;
    return path;
  }

  // the error message of loading path, or "" when it loads
  static std::string ErrorOf(const std::string& path) {
    try {
      ReadTetMesh(path);
    } catch (const Error& e) {
      return e.what();
    }
    return "";
  }

  std::filesystem::path dir_;
};

// a valid MSH 2.2 file with two tetrahedra sharing a face; parts replaceable
std::string Msh22(const std::string& nodes, const std::string& elements) {
  return "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n" + nodes + "$EndNodes\n$Elements\n" +
         elements + "$EndElements\n";
}
const std::string kNodes = "5\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n5 1 1 1\n";
const std::string kElements = "2\n1 4 0 1 2 3 4\n2 4 0 2 3 4 5\n";

TEST_F(BadInput, ValidBaselineLoads) {
  EXPECT_EQ(ErrorOf(Write("ok.msh", Msh22(kNodes, kElements))), "");
}

TEST_F(BadInput, MissingFile) {
  std::string message = ErrorOf((dir_ / "nope.msh").string());
  EXPECT_NE(message.find("nope.msh: cannot open"), std::string::npos) << message;
}

TEST_F(BadInput, Directory) {
  EXPECT_NE(ErrorOf(dir_.string()).find("is a directory"), std::string::npos);
}

TEST_F(BadInput, TruncatedTextFile) {
  std::string full = Msh22(kNodes, kElements);
  std::string path = Write("cut.msh", full.substr(0, full.find("$Elements") + 14));
  std::string message = ErrorOf(path);
  EXPECT_NE(message.find("truncated"), std::string::npos) << message;
  EXPECT_NE(message.find("cut.msh:"), std::string::npos) << message;
}

TEST_F(BadInput, TruncatedBinaryFiles) {
  for (const char* file : {"sphere_msh22_binary.msh", "sphere_msh41_binary.msh"}) {
    std::string content = ReadFileContents(kData + "/" + file);
    for (size_t cut : {content.size() / 3, content.size() / 2, content.size() - 20}) {
      std::string message = ErrorOf(Write("cut_binary.msh", content.substr(0, cut)));
      EXPECT_NE(message.find("truncated"), std::string::npos)
          << file << " cut at " << cut << ": " << message;
    }
  }
}

// MSH 2.2 binary: an element block's header (type, count, tags, as 32-bit
// integers after the section's count line) contradicting the section
TEST_F(BadInput, BinaryElementBlockHeader) {
  const std::string content = ReadFileContents(kData + "/sphere_msh22_binary.msh");
  const size_t section = content.find("$Elements\n");
  ASSERT_NE(section, std::string::npos);
  const size_t block = content.find('\n', section + 10) + 1;  // (after the count line)
  const int declared = std::stoi(content.substr(section + 10));
  auto with = [&](int field, std::int32_t value) {
    std::string changed = content;
    std::memcpy(changed.data() + block + 4 * field, &value, 4);
    return changed;
  };
  std::string message = ErrorOf(Write("f.msh", with(1, declared + 1)));
  EXPECT_NE(message.find("an element block holds " + std::to_string(declared + 1) +
                         " elements, where 1 to " + std::to_string(declared) + " remain"),
            std::string::npos)
      << message;
  message = ErrorOf(Write("t.msh", with(2, 100)));
  EXPECT_NE(message.find("an element block has 100 tags an element, outside 0 to 64"),
            std::string::npos)
      << message;
}

TEST_F(BadInput, UnknownFormat) {
  std::string message = ErrorOf(Write("mesh.xyz", "hello\n"));
  EXPECT_NE(message.find("unknown mesh format"), std::string::npos) << message;
}

TEST_F(BadInput, UnsupportedMshVersion) {
  std::string message = ErrorOf(Write("v3.msh", "$MeshFormat\n3.0 0 8\n$EndMeshFormat\n"));
  EXPECT_NE(message.find("MSH version 3.0 is not supported"), std::string::npos) << message;
  EXPECT_NE(message.find("v3.msh:2:"), std::string::npos) << message;
}

TEST_F(BadInput, NonFiniteCoordinate) {
  std::string nodes = "5\n1 0 0 0\n2 1 0 0\n3 0 nan 0\n4 0 0 1\n5 1 1 1\n";
  std::string message = ErrorOf(Write("nan.msh", Msh22(nodes, kElements)));
  EXPECT_NE(message.find("node 3 (line 8) has a non-finite coordinate"), std::string::npos)
      << message;
  nodes = "5\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 inf\n5 1 1 1\n";
  EXPECT_NE(ErrorOf(Write("inf.msh", Msh22(nodes, kElements))).find("node 4"), std::string::npos);
}

TEST_F(BadInput, NodeIndexOutOfRange) {
  std::string message =
      ErrorOf(Write("range.msh", Msh22(kNodes, "2\n1 4 0 1 2 3 4\n2 4 0 2 3 4 9\n")));
  EXPECT_NE(message.find("element 2"), std::string::npos) << message;
  EXPECT_NE(message.find("node 9"), std::string::npos) << message;
  // the same in TetGen and VTK
  std::string node = Write("r.node", "4 3 0 0\n0 0 0 0\n1 1 0 0\n2 0 1 0\n3 0 0 1\n");
  Write("r.ele", "1 4 0\n0 0 1 2 7\n");
  message = ErrorOf(node);
  EXPECT_NE(message.find("r.ele:2: tetrahedron 0 refers to point 7"), std::string::npos) << message;
  message = ErrorOf(Write("r.vtk",
                          "# vtk DataFile Version 3.0\nx\nASCII\nDATASET UNSTRUCTURED_GRID\n"
                          "POINTS 4 double\n0 0 0 1 0 0 0 1 0 0 0 1\nCELLS 1 5\n4 0 1 2 4\n"
                          "CELL_TYPES 1\n10\n"));
  EXPECT_NE(message.find("r.vtk:8: cell 0 refers to point 4"), std::string::npos) << message;
}

TEST_F(BadInput, MalformedNumber) {
  std::string nodes = "5\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1x\n5 1 1 1\n";
  std::string message = ErrorOf(Write("num.msh", Msh22(nodes, kElements)));
  EXPECT_NE(message.find("num.msh:9: expected z (a number), found '1x'"), std::string::npos)
      << message;
}

TEST_F(BadInput, DegenerateTetrahedron) {
  std::string nodes = "5\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 1 1 0\n5 1 1 1\n";
  std::string message = ErrorOf(Write("flat.msh", Msh22(nodes, "1\n1 4 0 1 2 3 4\n")));
  EXPECT_NE(message.find("element 1 (line 14) is degenerate"), std::string::npos) << message;
}

TEST_F(BadInput, RepeatedVertexInATetrahedron) {
  std::string message = ErrorOf(Write("rep.msh", Msh22(kNodes, "1\n1 4 0 1 2 2 4\n")));
  EXPECT_NE(message.find("uses the same vertex twice"), std::string::npos) << message;
}

TEST_F(BadInput, DuplicateTetrahedra) {
  std::string message =
      ErrorOf(Write("dup.msh", Msh22(kNodes, "2\n1 4 0 1 2 3 4\n2 4 0 4 3 2 1\n")));
  EXPECT_NE(message.find("repeats element 1"), std::string::npos) << message;
}

TEST_F(BadInput, NonManifoldEdge) {
  // two tetrahedra sharing only the edge 1-2
  std::string nodes = "6\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n5 0 -1 0\n6 0 0 -1\n";
  std::string message =
      ErrorOf(Write("edge.msh", Msh22(nodes, "2\n1 4 0 1 2 3 4\n2 4 0 1 2 5 6\n")));
  EXPECT_NE(message.find("belongs to 4 boundary triangles"), std::string::npos) << message;
}

TEST_F(BadInput, NonManifoldVertex) {
  // two tetrahedra sharing only vertex 1
  std::string nodes = "7\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n5 -1 0 0\n6 0 -1 0\n7 0 0 -1\n";
  std::string message =
      ErrorOf(Write("vertex.msh", Msh22(nodes, "2\n1 4 0 1 2 3 4\n2 4 0 1 5 6 7\n")));
  EXPECT_NE(message.find("not manifold at node 1"), std::string::npos) << message;
}

TEST_F(BadInput, FaceSharedByThreeTetrahedra) {
  std::string nodes = "6\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n5 0 0 -1\n6 0.1 0.1 2\n";
  std::string message =
      ErrorOf(Write("three.msh", Msh22(nodes, "3\n1 4 0 1 2 3 4\n2 4 0 1 2 3 5\n3 4 0 1 2 3 6\n")));
  EXPECT_NE(message.find("shared by 3 tetrahedra"), std::string::npos) << message;
}

TEST_F(BadInput, OverlappingTetrahedra) {
  std::string nodes = "5\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n5 0.1 0.1 2\n";
  std::string message =
      ErrorOf(Write("overlap.msh", Msh22(nodes, "2\n1 4 0 1 2 3 4\n2 4 0 1 2 3 5\n")));
  EXPECT_NE(message.find("overlap"), std::string::npos) << message;
}

TEST_F(BadInput, NoTetrahedra) {
  std::string message = ErrorOf(Write("surf.msh", Msh22(kNodes, "1\n1 2 0 1 2 3\n")));
  EXPECT_NE(message.find("no tetrahedra"), std::string::npos) << message;
}

TEST_F(BadInput, NodeDefinedTwice) {
  std::string nodes = "5\n1 0 0 0\n2 1 0 0\n3 0 1 0\n3 0 0 1\n5 1 1 1\n";
  std::string message = ErrorOf(Write("twice.msh", Msh22(nodes, kElements)));
  EXPECT_NE(message.find("node 3 is defined twice"), std::string::npos) << message;
}

TEST_F(BadInput, UnreferencedVerticesAreOnlyAWarning) {
  std::string nodes = "6\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n5 1 1 1\n6 7 7 7\n";
  TetMesh mesh = ReadTetMesh(Write("extra.msh", Msh22(nodes, kElements)));
  EXPECT_EQ(mesh.num_vertices(), 5);
  ASSERT_EQ(mesh.warnings().size(), 1u);
}

TEST_F(BadInput, VtkProblems) {
  const std::string header = "# vtk DataFile Version 3.0\nx\nASCII\nDATASET UNSTRUCTURED_GRID\n";
  std::string message = ErrorOf(Write("b.vtk", "# vtk DataFile Version 3.0\nx\nBINARY\n"));
  EXPECT_NE(message.find("b.vtk: byte 36: unexpected end of file: expected DATASET"),
            std::string::npos)
      << message;
  message = ErrorOf(Write("bit.vtk",
                          "# vtk DataFile Version 3.0\nx\nBINARY\nDATASET UNSTRUCTURED_GRID\n"
                          "POINTS 1 bit\n" +
                              std::string(12, '\0')));
  EXPECT_NE(message.find("bit.vtk: byte 74: the data type 'bit' of the point coordinates cannot "
                         "be read from a binary file"),
            std::string::npos)
      << message;
  EXPECT_NE(ErrorOf(Write("s.vtk",
                          "# vtk DataFile Version 3.0\nx\nASCII\nDATASET "
                          "STRUCTURED_POINTS\n"))
                .find("not supported"),
            std::string::npos);
  message = ErrorOf(Write("t.vtk", header + "POINTS 4 double\n0 0 0 1 0 0 0 1 0 0 0 "
                                            "1\nCELLS 1 5\n4 0 1 2 3\nCELL_TYPES 2\n10\n10\n"));
  EXPECT_NE(message.find("CELL_TYPES lists 2 cells but CELLS has 1"), std::string::npos) << message;
  message = ErrorOf(Write("h.vtk", "hello\n"));
  EXPECT_NE(message.find("h.vtk:1: not a legacy VTK file"), std::string::npos) << message;
  // a cell's vertex count beyond the list (versions 2 to 4.2)
  const std::string points = "POINTS 4 double\n0 0 0 1 0 0 0 1 0 0 0 1\n";
  message = ErrorOf(Write("c.vtk", header + points + "CELLS 1 5\n9 0 1 2 3\nCELL_TYPES 1\n10\n"));
  EXPECT_NE(
      message.find("c.vtk:8: cell 0 has a vertex count of 9, outside 0 to the 4 entries the CELLS "
                   "size 5 leaves it"),
      std::string::npos)
      << message;
  // (a count within the size, but past what the cells before it leave)
  message = ErrorOf(Write("l.vtk", header + points + "CELLS 1 4\n4 0 1 2 3\nCELL_TYPES 1\n10\n"));
  EXPECT_NE(message.find("l.vtk:8: cell 0 has a vertex count of 4, outside 0 to the 3 entries"),
            std::string::npos)
      << message;
  // a FIELD array whose size overflows (it wrapped to no values, and the
  // file read on)
  message = ErrorOf(Write("f.vtk", header + "FIELD FieldData 1\nt 4294967296 4294967296 double\n" +
                                       points + "CELLS 1 5\n4 0 1 2 3\nCELL_TYPES 1\n10\n"));
  EXPECT_NE(message.find("f.vtk:6: a FIELD array of 4294967296 components and 4294967296 tuples"),
            std::string::npos)
      << message;
  // offsets that fall, or pass the connectivity (version 5.1)
  const std::string header51 = "# vtk DataFile Version 5.1\nx\nASCII\nDATASET UNSTRUCTURED_GRID\n";
  message = ErrorOf(Write("o.vtk", header51 + points +
                                       "CELLS 3 4\nOFFSETS vtktypeint64\n0 4 2\n"
                                       "CONNECTIVITY vtktypeint64\n0 1 2 3\nCELL_TYPES 1\n10\n"));
  EXPECT_NE(message.find("OFFSETS value 2 (2) is below the one before it (4)"), std::string::npos)
      << message;
  message = ErrorOf(Write("p.vtk", header51 + points +
                                       "CELLS 2 4\nOFFSETS vtktypeint64\n0 6\n"
                                       "CONNECTIVITY vtktypeint64\n0 1 2 3\nCELL_TYPES 1\n10\n"));
  EXPECT_NE(message.find("OFFSETS value 1 (6) is beyond the 4 CONNECTIVITY entries"),
            std::string::npos)
      << message;
}

// a valid ascii .vtu of one tetrahedron; parts replaceable
std::string Vtu(const std::string& root_attributes, const std::string& points,
                const std::string& connectivity, const std::string& offsets = "4",
                const std::string& types = "10",
                const std::string& piece = "4\" NumberOfCells=\"1") {
  return "<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\"" + root_attributes +
         ">\n<UnstructuredGrid>\n<Piece NumberOfPoints=\"" + piece +
         "\">\n<Points>\n<DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">\n" +
         points + "\n</DataArray>\n</Points>\n<Cells>\n" +
         "<DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">\n" + connectivity +
         "\n</DataArray>\n<DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">" + offsets +
         "</DataArray>\n<DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">" + types +
         "</DataArray>\n</Cells>\n</Piece>\n</UnstructuredGrid>\n</VTKFile>\n";
}
const std::string kVtuPoints = "0 0 0\n1 0 0\n0 1 0\n0 0 1";

TEST_F(BadInput, VtuProblems) {
  ASSERT_EQ(ErrorOf(Write("ok.vtu", Vtu("", kVtuPoints, "0 1 2 3"))), "");
  // not XML, not an unstructured grid, a compressor it cannot unpack
  std::string message = ErrorOf(Write("x.vtu", "<VTKFile type=\"UnstructuredGrid\">\n<Piece>\n"));
  EXPECT_NE(message.find("x.vtu:2: not well-formed XML: an element is not closed"),
            std::string::npos)
      << message;
  message = ErrorOf(Write("p.vtu", "<VTKFile type=\"PolyData\"><PolyData/></VTKFile>"));
  EXPECT_NE(message.find("p.vtu:1: a VTK XML file of type 'PolyData' holds no tetrahedra"),
            std::string::npos)
      << message;
  message =
      ErrorOf(Write("z.vtu", Vtu(" compressor=\"vtkLZ4DataCompressor\"", kVtuPoints, "0 1 2 3")));
  EXPECT_NE(message.find("z.vtu:2: compressor 'vtkLZ4DataCompressor' is not supported"),
            std::string::npos)
      << message;
  // ascii arrays: too few values, a bad number, a bad count
  message = ErrorOf(Write("f.vtu", Vtu("", "0 0 0\n1 0 0\n0 1 0\n0 0", "0 1 2 3")));
  EXPECT_NE(message.find("f.vtu:11: DataArray '' holds 11 values; its piece needs 12"),
            std::string::npos)
      << message;
  message = ErrorOf(Write("n.vtu", Vtu("", "0 0 0\n1 0 0\n0 1.5x 0\n0 0 1", "0 1 2 3")));
  EXPECT_NE(message.find("n.vtu:9: DataArray '': '1.5x' is not a number"), std::string::npos)
      << message;
  message = ErrorOf(Write("c.vtu", Vtu("", kVtuPoints, "0 1 2 3", "4", "10", "-4")));
  EXPECT_NE(message.find("c.vtu:4: NumberOfPoints=\"-4\" is not a count"), std::string::npos)
      << message;
  // cells: out-of-range point, falling offsets, a tetrahedron of 3 points,
  // indices that are not whole numbers
  message = ErrorOf(Write("r.vtu", Vtu("", kVtuPoints, "0 1\n2 9")));
  EXPECT_NE(message.find("r.vtu:15: cell 0 refers to point 9, outside its piece's 4 points"),
            std::string::npos)
      << message;
  message = ErrorOf(
      Write("o.vtu", Vtu("", kVtuPoints, "0 1 2 3 0 1 2", "4 3", "10 5", "4\" NumberOfCells=\"2")));
  EXPECT_NE(message.find("o.vtu:17: DataArray 'offsets' value 1 (3) is below the one before it"),
            std::string::npos)
      << message;
  message = ErrorOf(Write("t.vtu", Vtu("", kVtuPoints, "0 1 2", "3")));
  EXPECT_NE(message.find("t.vtu:15: cell 0 has type 10 (a tetrahedron of 4 points) but 3 points"),
            std::string::npos)
      << message;
  std::string floats = Vtu("", kVtuPoints, "0 1 2 3");
  floats.replace(floats.find("Int64\" Name=\"connectivity"), 5, "Float32");
  message = ErrorOf(Write("i.vtu", floats));
  EXPECT_NE(message.find("i.vtu:14: DataArray 'connectivity' holds Float32 values"),
            std::string::npos)
      << message;
  // an appended array with no appended data
  std::string appended = Vtu("", kVtuPoints, "0 1 2 3");
  appended.replace(appended.find("format=\"ascii\">\n0 1 2 3"), 24,
                   "format=\"appended\" offset=\"0\">");
  message = ErrorOf(Write("a.vtu", appended));
  EXPECT_NE(message.find("a.vtu:14: DataArray 'connectivity' is appended, but the file has no "
                         "<AppendedData>"),
            std::string::npos)
      << message;
}

// binary .vtu files written by VTK (scripts/make-test-data), damaged
TEST_F(BadInput, VtuBinaryDamage) {
  const std::string raw = ReadFileContents(kData + "/sphere_vtk_appended_raw_zlib.vtu");
  const size_t data = raw.find('_', raw.find("<AppendedData")) + 1;
  ASSERT_EQ(ErrorOf(Write("ok.vtu", raw)), "");
  // cut inside the data, closed again: the blocks end early
  std::string message =
      ErrorOf(Write("cut.vtu", raw.substr(0, data + 600) + "\n</AppendedData>\n</VTKFile>\n"));
  EXPECT_NE(message.find("cut.vtu:9: DataArray 'Points''s binary data ends before its compressed "
                         "blocks"),
            std::string::npos)
      << message;
  EXPECT_NE(message.find("the file is cut short or damaged"), std::string::npos) << message;
  // cut, never closed
  message = ErrorOf(Write("open.vtu", raw.substr(0, data + 600)));
  EXPECT_NE(message.find("<AppendedData> must hold '_' and then the data"), std::string::npos)
      << message;
  // the points' compressed bytes changed (after their header of four UInt64)
  std::string changed = raw;
  for (size_t i = data + 40; i < data + 48; ++i) changed[i] = static_cast<char>(~changed[i]);
  message = ErrorOf(Write("zlib.vtu", changed));
  EXPECT_NE(message.find("zlib.vtu:9: DataArray 'Points''s compressed block 0 does not unpack"),
            std::string::npos)
      << message;
  // a block count no file could hold (the header's first UInt64, little-endian)
  std::string blocks = raw;
  blocks[data + 7] = 0x7F;
  message = ErrorOf(Write("blocks.vtu", blocks));
  EXPECT_NE(message.find("blocks.vtu:9: DataArray 'Points' has a compression header of"),
            std::string::npos)
      << message;
  // a character that is not base64 in an inline array
  std::string base64 = ReadFileContents(kData + "/sphere_vtk_binary.vtu");
  const size_t text = base64.find('>', base64.find("Name=\"connectivity\"")) + 1;
  base64[base64.find_first_not_of(" \n", text) + 5] = '*';
  message = ErrorOf(Write("b64.vtu", base64));
  EXPECT_NE(
      message.find("DataArray 'connectivity''s binary data holds '*', not a base64 character"),
      std::string::npos)
      << message;
}

// binary legacy .vtk files written by VTK (scripts/make-test-data), damaged
TEST_F(BadInput, VtkBinaryDamage) {
  const std::string v42 = ReadFileContents(kData + "/sphere_vtk42_binary.vtk");
  ASSERT_EQ(ErrorOf(Write("ok.vtk", v42)), "");
  // cut inside the points
  std::string message = ErrorOf(Write("cut.vtk", v42.substr(0, 1000)));
  EXPECT_NE(message.find("cut.vtk: byte 88: the file claims 186 point coordinates but has only "
                         "912 bytes left"),
            std::string::npos)
      << message;
  // the first cell's vertex count (a big-endian int after "CELLS 129 645\n")
  std::string count = v42;
  const size_t cells = count.find('\n', count.find("CELLS 129 645")) + 1;
  count[cells] = 0x7F;
  message = ErrorOf(Write("count.vtk", count));
  EXPECT_NE(message.find("count.vtk: byte " + std::to_string(cells + 4) +
                         ": cell 0 has a vertex count of 2130706436, outside 0 to the 644 entries"),
            std::string::npos)
      << message;
  // version 5.1's connectivity said to be float
  std::string v51 = ReadFileContents(kData + "/sphere_vtk51_binary.vtk");
  v51.replace(v51.find("CONNECTIVITY vtktypeint64"), 25, "CONNECTIVITY double      ");
  message = ErrorOf(Write("float.vtk", v51));
  EXPECT_NE(message.find("expected a cell vertex, an integer, but the array holds floating-point "
                         "values"),
            std::string::npos)
      << message;
}

// MSH 4.1 blocks whose headers contradict their sections
TEST_F(BadInput, MshBlockHeaders) {
  const std::string head = "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n";
  const std::string nodes = "1\n2\n3\n4\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n$EndNodes\n";
  const std::string elements = "$Elements\n1 1 1 1\n3 1 4 1\n1 1 2 3 4\n$EndElements\n";
  ASSERT_EQ(ErrorOf(Write("ok.msh", head + "1 4 1 4\n3 1 0 4\n" + nodes + elements)), "");
  EXPECT_NE(ErrorOf(Write("d.msh", head + "1 4 1 4\n5 1 0 4\n" + nodes + elements))
                .find("d.msh:6: a node block's entity dimension is 5, outside 0 to 3"),
            std::string::npos);
  EXPECT_NE(ErrorOf(Write("n.msh", head + "1 3 1 4\n3 1 0 4\n" + nodes + elements))
                .find("n.msh:6: the node blocks hold more than the 3 nodes the section declares"),
            std::string::npos);
  // (a sum past the largest long, which overflowed in the check)
  const std::string huge = "9223372036854775807";
  EXPECT_NE(ErrorOf(Write("h.msh", head + "2 " + huge + " 1 4\n3 1 0 1\n1\n0 0 0\n3 1 0 " + huge +
                                       "\n" + nodes + elements))
                .find("h.msh:9: the node blocks hold more than the " + huge + " nodes"),
            std::string::npos);
  const std::string more = "$Elements\n1 0 1 1\n3 1 4 1\n1 1 2 3 4\n$EndElements\n";
  EXPECT_NE(ErrorOf(Write("e.msh", head + "1 4 1 4\n3 1 0 4\n" + nodes + more))
                .find("e.msh:18: the element blocks hold more than the 0 elements the section "
                      "declares"),
            std::string::npos);
}

TEST_F(BadInput, TetGenProblems) {
  std::string node = Write("d.node", "4 2 0 0\n");
  Write("d.ele", "0 4 0\n");
  EXPECT_NE(ErrorOf(node).find("dimension 2 is not 3"), std::string::npos);
  Write("a.ele", "0 4 0\n");
  Write("k.ele", "0 4 0\n");
  EXPECT_NE(ErrorOf(Write("a.node", "4 3 -1 0\n"))
                .find("a.node:1: the number of point attributes is -1; give 0 or more"),
            std::string::npos);
  // counts past the file, and region numbers beyond an int (the cast was
  // undefined)
  Write("h.ele", "0 4 0\n");
  EXPECT_NE(ErrorOf(Write("h.node", "4 3 9223372036854775807 1\n0 0 0 0\n"))
                .find("h.node:1: the file claims 9223372036854775807 point attributes"),
            std::string::npos);
  const std::string tet_nodes = "4 3 0 0\n0 0 0 0\n1 1 0 0\n2 0 1 0\n3 0 0 1\n";
  Write("r.ele", "1 4 1\n0 0 1 2 3 1e300\n");
  EXPECT_NE(ErrorOf(Write("r.node", tet_nodes))
                .find("r.ele:2: tetrahedron 0's region attribute is 1e+300; a region number must "
                      "be finite"),
            std::string::npos);
  Write("s.ele", "1 4 1\n0 0 1 2 3 nan\n");
  EXPECT_NE(ErrorOf(Write("s.node", tet_nodes)).find("region attribute is nan"), std::string::npos);
  EXPECT_NE(ErrorOf(Write("k.node", "4 3 0 2\n"))
                .find("k.node:1: the number of boundary markers is 2; TetGen writes 0 or 1"),
            std::string::npos);
  std::string missing = Write("m.node", "4 3 0 0\n0 0 0 0\n1 1 0 0\n2 0 1 0\n3 0 0 1\n");
  EXPECT_NE(ErrorOf(missing).find("m.ele: cannot open"), std::string::npos);
}

// The names an error offers in place of a missing one: every name, in
// order, joined as a sentence, up to the limit, then how many are left out.
TEST(QuotedList, ListsUpToTheLimitAndCountsTheRest) {
  const std::vector<std::string_view> names = {"a", "b", "c", "d", "e"};
  EXPECT_EQ(QuotedList({}), "");
  EXPECT_EQ(QuotedList(std::span(names).first(1)), "'a'");
  EXPECT_EQ(QuotedList(std::span(names).first(2)), "'a' and 'b'");
  EXPECT_EQ(QuotedList(names), "'a', 'b', 'c', 'd' and 'e'");
  EXPECT_EQ(QuotedList(names, 5), "'a', 'b', 'c', 'd' and 'e'");
  EXPECT_EQ(QuotedList(names, 4), "'a', 'b', 'c', 'd' and 1 more");
  EXPECT_EQ(QuotedList(names, 2), "'a', 'b' and 3 more");
  EXPECT_EQ(QuotedList(names, 0), "'a' and 4 more");  // (at least one shown)
}

}  // namespace
}  // namespace tetcosim
