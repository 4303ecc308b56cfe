// Every kind of bad input gets its own clear error: which file, which line
// or element, what is wrong.

#include <gtest/gtest.h>

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
  EXPECT_NE(ErrorOf(Write("b.vtk", "# vtk DataFile Version 3.0\nx\nBINARY\n")).find("binary"),
            std::string::npos);
  EXPECT_NE(ErrorOf(Write("s.vtk",
                          "# vtk DataFile Version 3.0\nx\nASCII\nDATASET "
                          "STRUCTURED_POINTS\n"))
                .find("not supported"),
            std::string::npos);
  std::string message =
      ErrorOf(Write("t.vtk", header + "POINTS 4 double\n0 0 0 1 0 0 0 1 0 0 0 "
                                      "1\nCELLS 1 5\n4 0 1 2 3\nCELL_TYPES 2\n10\n10\n"));
  EXPECT_NE(message.find("CELL_TYPES lists 2 cells but CELLS has 1"), std::string::npos) << message;
  message = ErrorOf(Write("h.vtk", "hello\n"));
  EXPECT_NE(message.find("h.vtk:1: not a legacy VTK file"), std::string::npos) << message;
}

TEST_F(BadInput, TetGenProblems) {
  std::string node = Write("d.node", "4 2 0 0\n");
  Write("d.ele", "0 4 0\n");
  EXPECT_NE(ErrorOf(node).find("dimension 2 is not 3"), std::string::npos);
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
