#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>

#include "mesh/error.h"
#include "mesh/generators.h"
#include "mesh/mesh_io.h"
#include "mesh/text_reader.h"

namespace tetcosim {
namespace {

std::string TempPath(const std::string& name) {
  return (std::filesystem::temp_directory_path() /
          ("tetcosim_" + std::to_string(::getpid()) + "_" + name))
      .string();
}

TEST(VtkWriter, LegacyRoundTripIsExact) {
  for (const char* spec : {"sphere:size=0.1:res=1", "torus:size=0.1,0.03:res=2",
                           "box:size=0.1,0.2,0.3:res=2:split=5"}) {
    SCOPED_TRACE(spec);
    TetMesh mesh = TetMesh::Build(MakeShape(spec));
    std::string path = TempPath("roundtrip.vtk");
    VtkData data;
    data.point_data.push_back({"value", 1, std::vector<double>(mesh.num_vertices(), 0.25)});
    WriteVtk(path, mesh.positions(), mesh.tets(), data);
    TetMesh back = ReadTetMesh(path);
    // shortest round-trip number formatting: bit-identical positions
    EXPECT_EQ(back.positions(), mesh.positions());
    EXPECT_EQ(back.tets(), mesh.tets());
    std::filesystem::remove(path);
  }
}

TEST(VtkWriter, VtuRoundTripIsExact) {
  for (const char* spec : {"sphere:size=0.1:res=1", "torus:size=0.1,0.03:res=2"}) {
    SCOPED_TRACE(spec);
    TetMesh mesh = TetMesh::Build(MakeShape(spec));
    std::string path = TempPath("roundtrip.vtu");
    VtkData data;
    data.point_data.push_back({"velocity", 3, std::vector<double>(3 * mesh.num_vertices(), 0.5)});
    WriteVtk(path, mesh.positions(), mesh.tets(), data);
    TetMesh back = ReadTetMesh(path);
    EXPECT_EQ(back.positions(), mesh.positions());
    EXPECT_EQ(back.tets(), mesh.tets());
    std::filesystem::remove(path);
  }
}

TEST(VtkWriter, VtuHasTheDeclaredCounts) {
  TetMesh mesh = TetMesh::Build(MakeShape("sphere:size=0.1:res=1"));
  std::string path = TempPath("mesh.vtu");
  VtkData data;
  data.point_data.push_back({"velocity", 3, std::vector<double>(3 * mesh.num_vertices(), 1.0)});
  data.cell_data.push_back({"volume", 1, {mesh.rest_volumes().begin(), mesh.rest_volumes().end()}});
  WriteVtk(path, mesh.positions(), mesh.tets(), data);
  std::string text = ReadFileContents(path);
  EXPECT_NE(text.find("NumberOfPoints=\"" + std::to_string(mesh.num_vertices()) + "\""),
            std::string::npos);
  EXPECT_NE(text.find("NumberOfCells=\"" + std::to_string(mesh.num_tets()) + "\""),
            std::string::npos);
  EXPECT_NE(text.find("Name=\"velocity\" NumberOfComponents=\"3\""), std::string::npos);
  EXPECT_FALSE(std::filesystem::exists(path + ".tmp"));

  // an independent reader, where the machine has it: meshio must read the
  // same counts and data back
  if (std::system("/usr/bin/python3 -c 'import meshio' 2>/dev/null") != 0) {
    GTEST_SKIP() << "python3-meshio not installed (scripts/install-deps installs it)";
  }
  std::string check = "/usr/bin/python3 -c \"import meshio,sys; m=meshio.read('" + path +
                      "'); sys.exit(0 if len(m.points)==" + std::to_string(mesh.num_vertices()) +
                      " and len(m.get_cells_type('tetra'))==" + std::to_string(mesh.num_tets()) +
                      " and m.point_data['velocity'].shape==(" +
                      std::to_string(mesh.num_vertices()) + ",3) else 1)\"";
  EXPECT_EQ(std::system(check.c_str()), 0) << check;
  std::filesystem::remove(path);
}

TEST(VtkWriter, WrongArraySizeAndUnwritablePathAreErrors) {
  TetMesh mesh = TetMesh::Build(MakeShape("sphere:size=0.1:res=0"));
  VtkData data;
  data.point_data.push_back({"bad", 1, {1.0, 2.0}});
  EXPECT_THROW(WriteVtk(TempPath("bad.vtu"), mesh.positions(), mesh.tets(), data), Error);
  EXPECT_THROW(WriteVtk("/nonexistent-dir/x.vtu", mesh.positions(), mesh.tets()), Error);
  // a folder is an error that says so, and leaves no temporary file beside it
  const std::string folder = TempPath("folder");
  std::filesystem::create_directory(folder);
  for (const std::string& path : {folder, folder + "/"}) {
    try {
      WriteVtk(path, mesh.positions(), mesh.tets());
      ADD_FAILURE() << "no error for " << path;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("is a folder"), std::string::npos) << e.what();
    }
    EXPECT_FALSE(std::filesystem::exists(path + ".tmp"));
  }
  std::filesystem::remove(folder);
}

}  // namespace
}  // namespace tetcosim
