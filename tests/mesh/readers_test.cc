// Every reader on files made by the real tools (scripts/make-test-data), with
// counts and volumes checked against python3-meshio's reading of the same
// files (tests/data/reference.tsv).

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string_view>

#include "mesh/mesh_io.h"
#include "mesh/text_reader.h"
#include "tests/support/mesh_checks.h"

namespace tetcosim {
namespace {

const std::string kData = TETCOSIM_TEST_DATA_DIR;

struct Reference {
  std::string file;
  int vertices;
  int tets;
  double volume;
};

std::vector<Reference> LoadReference() {
  std::ifstream in(kData + "/reference.tsv");
  std::string line;
  std::getline(in, line);  // header
  std::vector<Reference> rows;
  while (std::getline(in, line)) {
    std::istringstream fields(line);
    Reference r;
    fields >> r.file >> r.vertices >> r.tets >> r.volume;
    rows.push_back(r);
  }
  return rows;
}

TEST(Readers, AgreeWithMeshio) {
  std::vector<Reference> rows = LoadReference();
  ASSERT_GE(rows.size(), 10u);
  for (const Reference& r : rows) {
    SCOPED_TRACE(r.file);
    TetMesh mesh = ReadTetMesh(kData + "/" + r.file);
    EXPECT_EQ(mesh.num_vertices(), r.vertices);
    EXPECT_EQ(mesh.num_tets(), r.tets);
    EXPECT_NEAR(mesh.total_volume(), r.volume, 1e-12 * r.volume);
    EXPECT_TRUE(testing::IsClosedOrientedSurface(mesh));
  }
}

TEST(Readers, GmshVariantsOfOneMeshAreIdentical) {
  RawMesh reference = ReadRawMesh(kData + "/sphere_msh22_ascii.msh");
  for (const char* file :
       {"sphere_msh22_binary.msh", "sphere_msh41_ascii.msh", "sphere_msh41_binary.msh",
        "sphere_meshio51.vtk", "sphere_gmsh_binary.vtk"}) {
    SCOPED_TRACE(file);
    RawMesh other = ReadRawMesh(kData + "/" + file);
    // ASCII files carry 16 significant digits, binary ones all 17
    ASSERT_EQ(other.positions.rows(), reference.positions.rows());
    EXPECT_LT((other.positions - reference.positions).cwiseAbs().maxCoeff(), 1e-16);
    EXPECT_EQ(other.tets, reference.tets);
  }
}

// VTK XML and binary legacy VTK files of the same mesh as written by VTK
// itself and by meshio, in every encoding (scripts/make-test-data): the
// binary ones hold the very doubles meshio read from sphere_msh41_ascii.msh,
// meshio's ascii .vtu 12 significant digits, VTK's ascii .vtk 11
TEST(Readers, VtkEncodingsOfOneMeshAreIdentical) {
  RawMesh reference = ReadRawMesh(kData + "/sphere_msh41_ascii.msh");
  for (const char* file :
       {"sphere_vtk_appended_raw_zlib.vtu", "sphere_vtk_appended_base64.vtu",
        "sphere_vtk_binary.vtu", "sphere_vtk_binary_zlib_be.vtu", "sphere_meshio_mixed_zlib.vtu",
        "sphere_meshio_ascii.vtu", "sphere_vtk42_binary.vtk", "sphere_vtk51_binary.vtk",
        "sphere_meshio51_binary.vtk", "sphere_vtk42_ascii.vtk"}) {
    SCOPED_TRACE(file);
    RawMesh other = ReadRawMesh(kData + "/" + file);
    ASSERT_EQ(other.positions.rows(), reference.positions.rows());
    if (std::string_view(file).find("ascii") != std::string_view::npos) {
      EXPECT_LT((other.positions - reference.positions).cwiseAbs().maxCoeff(), 1e-11 * 0.05);
    } else {
      EXPECT_EQ(other.positions, reference.positions);
    }
    EXPECT_EQ(other.tets, reference.tets);
  }
  // the triangles and lines of the whole Gmsh mesh are left out, and the
  // tetrahedra keep their cell numbers
  RawMesh mixed = ReadRawMesh(kData + "/sphere_meshio_mixed_zlib.vtu");
  ASSERT_FALSE(mixed.element_ids.empty());
  EXPECT_GT(mixed.element_ids.front(), 0);
}

TEST(Readers, BinaryLegacyVtkOfSmallSignedTypes) {
  // big-endian shorts, negative ones among them, for the points; ints for
  // the cells (as VTK writes them before version 5)
  auto big_endian = [](long value, int size) {
    std::string bytes;
    for (int i = size - 1; i >= 0; --i) bytes.push_back(static_cast<char>(value >> (8 * i) & 0xFF));
    return bytes;
  };
  std::string vtk =
      "# vtk DataFile Version 3.0\nshorts\nBINARY\nDATASET UNSTRUCTURED_GRID\n"
      "POINTS 4 short\n";
  for (long x : {-1, -2, -3, 300, -2, -3, -1, 300, -3, -1, -2, 300}) vtk += big_endian(x, 2);
  vtk += "\nCELLS 1 5\n";
  for (long i : {4, 0, 1, 2, 3}) vtk += big_endian(i, 4);
  vtk += "\nCELL_TYPES 1\n" + big_endian(10, 4) + "\n";
  RawMesh raw = ReadVtkLegacy("shorts.vtk", vtk);
  ASSERT_EQ(raw.positions.rows(), 4);
  EXPECT_EQ(raw.positions.row(0), Eigen::RowVector3d(-1, -2, -3));
  EXPECT_EQ(raw.positions.row(3), Eigen::RowVector3d(-1, -2, 300));
  EXPECT_EQ(raw.tets.row(0), Eigen::RowVector4i(0, 1, 2, 3));
}

TEST(Readers, VtuPiecesAreJoinedAndOtherCellsSkipped) {
  // two pieces of one tetrahedron each (the second with a triangle before
  // it), ascii, no <?xml?> line, and no extension to tell the format
  auto piece = [](const std::string& x, const std::string& connectivity, const std::string& offsets,
                  const std::string& types, int cells) {
    return "<Piece NumberOfPoints=\"4\" NumberOfCells=\"" + std::to_string(cells) +
           "\">\n<Points><DataArray type=\"Float32\" NumberOfComponents=\"3\">\n" + x +
           " 0 0  1 0 0  0 1 0  0 0 1\n</DataArray></Points>\n<Cells>\n"
           "<DataArray type=\"Int32\" Name=\"connectivity\">" +
           connectivity + "</DataArray>\n<DataArray type=\"Int32\" Name=\"offsets\">" + offsets +
           "</DataArray>\n<DataArray type=\"UInt8\" Name=\"types\">" + types +
           "</DataArray>\n</Cells>\n</Piece>\n";
  };
  const std::string vtu =
      "<VTKFile type=\"UnstructuredGrid\" version=\"0.1\">\n<UnstructuredGrid>\n" +
      piece("0", "0 1 2 3", "4", "10", 1) + piece("2", "0 1 2\n1 0 2 3", "3 7", "5 10", 2) +
      "</UnstructuredGrid>\n</VTKFile>\n";
  RawMesh raw = ReadVtu("pieces", vtu);
  ASSERT_EQ(raw.positions.rows(), 8);
  EXPECT_EQ(raw.positions(4, 0), 2.0);
  ASSERT_EQ(raw.tets.rows(), 2);
  EXPECT_EQ(raw.tets.row(0), Eigen::RowVector4i(0, 1, 2, 3));
  EXPECT_EQ(raw.tets.row(1), Eigen::RowVector4i(5, 4, 6, 7));
  EXPECT_EQ(raw.element_ids, (std::vector<long>{0, 2}));
  EXPECT_EQ(raw.element_lines, (std::vector<long>{8, 19}));
  EXPECT_EQ(raw.node_lines[5], 15);
}

// Second-order meshes of the same shapes (scripts/make-test-data): read as
// the linear mesh of their corners, with a warning that says so. Gmsh and
// TetGen make the second-order mesh by adding nodes to the linear one, so
// the corners are the linear mesh's vertices.
TEST(Readers, SecondOrderTetrahedraAreReadFromTheirCorners) {
  auto sorted_rows = [](const Positions& x) {
    std::vector<std::array<double, 3>> rows;
    for (Eigen::Index v = 0; v < x.rows(); ++v) rows.push_back({x(v, 0), x(v, 1), x(v, 2)});
    std::sort(rows.begin(), rows.end());
    return rows;
  };
  TetMesh linear = ReadTetMesh(kData + "/lshape_msh22_ascii.msh");
  for (const char* file : {"lshape_order2_msh41.msh", "lshape_order2_msh22_binary.msh",
                           "lshape_order2_meshio.vtu", "lshape_order2_meshio51.vtk"}) {
    SCOPED_TRACE(file);
    TetMesh mesh = ReadTetMesh(kData + "/" + file);
    ASSERT_FALSE(mesh.warnings().empty());
    EXPECT_EQ(mesh.warnings()[0].find("178 higher-order tetrahedra were read as linear ones"), 0u);
    EXPECT_EQ(mesh.num_tets(), linear.num_tets());
    ASSERT_EQ(mesh.num_vertices(), linear.num_vertices());
    EXPECT_NEAR(mesh.total_volume(), linear.total_volume(), 1e-14 * linear.total_volume());
    const auto rows = sorted_rows(mesh.positions()), linear_rows = sorted_rows(linear.positions());
    for (size_t v = 0; v < rows.size(); ++v) {
      for (int k = 0; k < 3; ++k) EXPECT_NEAR(rows[v][k], linear_rows[v][k], 1e-16);
    }
  }
  TetMesh tetgen = ReadTetMesh(kData + "/sphere_tetgen_order2.ele");
  TetMesh tetgen_linear = ReadTetMesh(kData + "/sphere_tetgen1.ele");
  ASSERT_FALSE(tetgen.warnings().empty());
  EXPECT_EQ(tetgen.warnings()[0].find("580 higher-order tetrahedra"), 0u);
  EXPECT_EQ(tetgen.positions(), tetgen_linear.positions());
  EXPECT_EQ(tetgen.tets(), tetgen_linear.tets());
}

TEST(Readers, PhysicalTagsAreKept) {
  for (const char* file : {"lshape_msh22_ascii.msh", "lshape_msh41_binary.msh"}) {
    SCOPED_TRACE(file);
    TetMesh mesh = ReadTetMesh(kData + "/" + file);
    ASSERT_EQ(mesh.tet_tags().size(), static_cast<size_t>(mesh.num_tets()));
    for (int tag : mesh.tet_tags()) EXPECT_EQ(tag, 7);
  }
}

TEST(Readers, TetGenRegionAttributesAndEitherFileName) {
  TetMesh by_ele = ReadTetMesh(kData + "/sphere_tetgen0.ele");
  TetMesh by_node = ReadTetMesh(kData + "/sphere_tetgen0.node");
  TetMesh by_base = ReadTetMesh(kData + "/sphere_tetgen0");
  EXPECT_EQ(by_ele.tets(), by_node.tets());
  EXPECT_EQ(by_ele.tets(), by_base.tets());
  EXPECT_EQ(by_ele.tet_tags().size(), static_cast<size_t>(by_ele.num_tets()));
  EXPECT_TRUE(ReadTetMesh(kData + "/sphere_tetgen1.ele").tet_tags().empty());
}

TEST(Readers, TetGenWithAttributesMarkersAndComments) {
  // one-based, two point attributes and a boundary marker, region attribute
  const std::string node =
      "# a hand-written TetGen file\n"
      "5 3 2 1\n"
      "1  0 0 0   0.5 7  1\n"
      "2  1 0 0   0.5 7  1\n"
      "3  0 1 0   0.5 7  1  # trailing comment\n"
      "4  0 0 1   0.5 7  1\n"
      "5  1 1 1   0.5 7  1\n";
  const std::string ele =
      "2 4 1\n"
      "1  1 2 3 4  3\n"
      "2  2 3 4 5  4\n";
  RawMesh raw = ReadTetGen("t.node", node, "t.ele", ele);
  TetMesh mesh = TetMesh::Build(raw);
  EXPECT_EQ(mesh.num_vertices(), 5);
  EXPECT_EQ(mesh.tet_tags(), (std::vector<int>{3, 4}));
  EXPECT_NEAR(mesh.total_volume(), 1.0 / 6.0 + 1.0 / 3.0, 1e-15);
}

TEST(Readers, GmshNonContiguousNodeTagsAndSeveralBlocks) {
  // MSH 4.1 ASCII with two node blocks, tags 10.. and 100.., a line element
  // and a triangle to skip, and tetrahedra in two element blocks
  const std::string msh =
      "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n"
      "$Nodes\n2 5 10 102\n"
      "3 1 0 3\n10\n11\n12\n0 0 0\n1 0 0\n0 1 0\n"
      "3 1 0 2\n101\n102\n0 0 1\n1 1 1\n"
      "$EndNodes\n"
      "$Elements\n4 4 1 9\n"
      "1 1 1 1\n1 10 11\n"
      "2 1 2 1\n2 10 11 12\n"
      "3 1 4 1\n7 10 11 12 101\n"
      "3 2 4 1\n9 11 12 101 102\n"
      "$EndElements\n";
  RawMesh raw = ReadGmsh("inline.msh", msh);
  EXPECT_EQ(raw.element_ids, (std::vector<long>{7, 9}));
  TetMesh mesh = TetMesh::Build(raw);
  EXPECT_EQ(mesh.num_tets(), 2);
  EXPECT_EQ(mesh.node_ids(), (std::vector<long>{10, 11, 12, 101, 102}));
}

TEST(Readers, BundledModelMeshesRead) {
  for (const char* file : {"sphere.msh", "torus.msh", "lshape.msh", "blob.msh"}) {
    SCOPED_TRACE(file);
    TetMesh mesh = ReadTetMesh(std::string(TETCOSIM_SOURCE_DIR) + "/models/meshes/" + file);
    EXPECT_GT(mesh.num_tets(), 500);
    EXPECT_TRUE(testing::IsClosedOrientedSurface(mesh));
    EXPECT_EQ(testing::SurfaceEulerCharacteristic(mesh), std::string(file) == "torus.msh" ? 0 : 2);
  }
}

}  // namespace
}  // namespace tetcosim
