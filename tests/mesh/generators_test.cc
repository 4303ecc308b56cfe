#include "mesh/generators.h"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <string>

#include "mesh/error.h"
#include "mesh/quality.h"
#include "tests/support/mesh_checks.h"

namespace tetcosim {
namespace {

using testing::EnclosedVolume;
using testing::IsClosedOrientedSurface;
using testing::SurfaceEulerCharacteristic;

struct ShapeCase {
  std::string spec;
  int euler;                // of the surface: 2 for genus 0, 0 for the torus
  double exact_volume;      // of the ideal shape
  double volume_tolerance;  // relative, for the discretised shape
};

void PrintTo(const ShapeCase& c, std::ostream* out) {
  *out << c.spec;
}

class GeneratorTest : public ::testing::TestWithParam<ShapeCase> {};

TEST_P(GeneratorTest, ValidClosedManifoldWithMatchingVolume) {
  const ShapeCase& c = GetParam();
  TetMesh mesh = TetMesh::Build(MakeShape(c.spec));
  EXPECT_EQ(mesh.num_flipped(), 0) << "generators emit positive tetrahedra";
  EXPECT_TRUE(mesh.warnings().empty());
  for (int t = 0; t < mesh.num_tets(); ++t) EXPECT_GT(mesh.rest_volumes()[t], 0.0);
  EXPECT_TRUE(IsClosedOrientedSurface(mesh));
  EXPECT_EQ(SurfaceEulerCharacteristic(mesh), c.euler);
  // divergence theorem: the outward surface encloses exactly the tets' volume
  EXPECT_NEAR(EnclosedVolume(mesh), mesh.total_volume(), 1e-12 * mesh.total_volume());
  EXPECT_NEAR(mesh.total_volume(), c.exact_volume, c.volume_tolerance * c.exact_volume);
  // no slivers from the maps
  MeshQuality quality = ComputeQuality(mesh);
  EXPECT_GT(quality.min_dihedral_deg, 5.0);
  EXPECT_LT(quality.max_dihedral_deg, 175.0);
}

constexpr double kPi = std::numbers::pi;

INSTANTIATE_TEST_SUITE_P(
    Shapes, GeneratorTest,
    ::testing::Values(
        ShapeCase{"box:size=0.1,0.2,0.3:res=3,4,5", 2, 8 * 0.1 * 0.2 * 0.3, 1e-12},
        ShapeCase{"box:size=0.1,0.2,0.3:res=3,4,5:split=5", 2, 8 * 0.1 * 0.2 * 0.3, 1e-12},
        ShapeCase{"box:size=1:res=1:split=5", 2, 8.0, 1e-12},
        // the icosahedron inscribed in the unit sphere: 2.536 of 4.189
        ShapeCase{"sphere:size=1:res=0", 2, 2.5361507101204, 1e-9},
        ShapeCase{"sphere:size=1:res=2", 2, 4.0 / 3.0 * kPi, 0.04},
        ShapeCase{"sphere:size=1:res=3", 2, 4.0 / 3.0 * kPi, 0.01},
        ShapeCase{"cylinder:size=0.1,0.2:res=6", 2, kPi * 0.01 * 0.4, 0.04},
        ShapeCase{"cylinder:size=0.1,0.2:res=1", 2, kPi * 0.01 * 0.4, 0.4},
        ShapeCase{"capsule:size=0.1,0.15:res=6", 2, kPi * 0.01 * 0.3 + 4.0 / 3.0 * kPi * 1e-3,
                  0.05},
        ShapeCase{"capsule:size=0.1,0.0001:res=4", 2, 4.0 / 3.0 * kPi * 1e-3, 0.1},
        ShapeCase{"torus:size=0.1,0.03:res=4", 0, 2 * kPi* kPi * 0.1 * 0.03 * 0.03, 0.05},
        ShapeCase{"torus:size=0.1,0.03:res=1", 0, 2 * kPi* kPi * 0.1 * 0.03 * 0.03, 0.45}),
    [](const ::testing::TestParamInfo<ShapeCase>& param_info) {
      std::string name = param_info.param.spec;
      for (char& c : name) {
        if (!std::isalnum(static_cast<unsigned char>(c))) c = '_';
      }
      return name;
    });

TEST(Generators, SphereResolutionZeroIsThePapersIcosahedron) {
  TetMesh mesh = TetMesh::Build(MakeSphere(0.5, 0));
  EXPECT_EQ(mesh.num_tets(), 20);
  EXPECT_EQ(mesh.num_vertices(), 13);
  EXPECT_EQ(mesh.surface().rows(), 20);
  EXPECT_EQ(mesh.surface_vertices().size(), 12u);
  for (int v : mesh.surface_vertices()) {
    EXPECT_NEAR(mesh.positions().row(v).norm(), 0.5, 1e-12);
  }
  // each refinement level splits every tetrahedron into 8
  EXPECT_EQ(TetMesh::Build(MakeSphere(0.5, 2)).num_tets(), 20 * 64);
}

TEST(Generators, SurfaceVerticesLieOnTheIdealShape) {
  TetMesh sphere = TetMesh::Build(MakeShape("sphere:size=0.2:res=2"));
  for (int v : sphere.surface_vertices()) {
    EXPECT_NEAR(sphere.positions().row(v).norm(), 0.2, 1e-12);
  }
  TetMesh torus = TetMesh::Build(MakeShape("torus:size=0.1,0.03:res=3"));
  for (int v : torus.surface_vertices()) {
    Eigen::Vector3d p = torus.positions().row(v);
    double ring = std::hypot(p.x(), p.y()) - 0.1;
    EXPECT_NEAR(std::hypot(ring, p.z()), 0.03, 1e-12);
  }
}

TEST(Generators, BoxCounts) {
  TetMesh six = TetMesh::Build(MakeBox({1, 1, 1}, {7, 7, 7}, 6));
  EXPECT_EQ(six.num_tets(), 2058);
  EXPECT_EQ(six.num_vertices(), 512);
  TetMesh five = TetMesh::Build(MakeBox({1, 1, 1}, {2, 3, 4}, 5));
  EXPECT_EQ(five.num_tets(), 5 * 24);
}

TEST(Generators, BadSpecsAreErrors) {
  for (const char* spec :
       {"box:size=0.1,0.1", "sphere:size=-1", "sphere:size=1:res=9", "torus:size=0.1,0.2",
        "cylinder:size=0.1", "box:size=1:split=4", "box:size=1:res=0", "capsule:size=a,b",
        "sphere:radius=1", "sphere:res=1"}) {
    EXPECT_THROW(MakeShape(spec), Error) << spec;
  }
  // sizes whose elements' volumes would overflow or underflow say so
  for (const char* spec : {"box:size=1e300:res=2", "box:size=1e-300:res=2", "sphere:size=0",
                           "capsule:size=0.1,inf", "box:size=1,nan,1"}) {
    try {
      MakeShape(spec);
      ADD_FAILURE() << spec << " was meshed";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("is not a length from 1e-9 to 1e9 metres"),
                std::string::npos)
          << e.what();
    }
  }
  EXPECT_TRUE(IsShapeSpec("torus:size=1,0.2"));
}

// Shapes whose sizes would make more than 2^24 tetrahedra (a slip in the
// sizes: a capsule a million radii long) are errors that say so, not hours
// of meshing; the error names the count.
TEST(Generators, ShapesTooFineToMeshAreErrors) {
  for (const char* spec : {"capsule:size=0.001,1000:res=3", "cylinder:size=1e-9,1e9:res=2",
                           "torus:size=1e9,1e-9:res=2", "box:size=1:res=256"}) {
    try {
      MakeShape(spec);
      ADD_FAILURE() << spec << " was meshed";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("tetrahedra, more than the 16777216"), std::string::npos)
          << e.what();
    }
  }
  EXPECT_FALSE(IsShapeSpec("models/meshes/torus.msh"));
  EXPECT_FALSE(IsShapeSpec("boxes.msh"));
}

}  // namespace
}  // namespace tetcosim
