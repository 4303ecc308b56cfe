#include "mesh/generators.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <numbers>
#include <random>
#include <string>
#include <utility>
#include <vector>

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

// Whether p is inside tetrahedron t of the mesh (its four sub-volumes all
// at least -tolerance times the tet's)
bool InTet(const TetMesh& mesh, int t, const Eigen::Vector3d& p, double tolerance) {
  std::array<Eigen::Vector3d, 4> x;
  for (int k = 0; k < 4; ++k) x[k] = mesh.positions().row(mesh.tets()(t, k)).transpose();
  const double volume = SignedTetVolume(x[0], x[1], x[2], x[3]);
  for (int k = 0; k < 4; ++k) {
    std::array<Eigen::Vector3d, 4> y = x;
    y[k] = p;
    if (SignedTetVolume(y[0], y[1], y[2], y[3]) < -tolerance * volume) return false;
  }
  return true;
}

// Oracles for a mesh of the same solid as `solid` (ConeToPoint,
// ConeToAxis): positive tetrahedra, the same surface (each triangle's
// corners where the solid's are), the same volume to rounding, and the same
// points inside (random points, brute force over both meshes' tetrahedra:
// inside one just when inside the other, but within 1e-9 of the surface).
void ExpectSameSolid(const TetMesh& solid, const TetMesh& coned) {
  EXPECT_EQ(coned.num_flipped(), 0);
  EXPECT_TRUE(coned.warnings().empty());
  EXPECT_TRUE(IsClosedOrientedSurface(coned));
  EXPECT_NEAR(coned.total_volume(), solid.total_volume(), 1e-12 * solid.total_volume());
  // the surfaces' triangles as sorted corner positions, sorted
  auto triangles = [](const TetMesh& mesh) {
    std::vector<std::array<std::array<double, 3>, 3>> all;
    for (Eigen::Index f = 0; f < mesh.surface().rows(); ++f) {
      std::array<std::array<double, 3>, 3> corners;
      for (int k = 0; k < 3; ++k) {
        const auto p = mesh.positions().row(mesh.surface()(f, k));
        corners[k] = {p.x(), p.y(), p.z()};
      }
      std::sort(corners.begin(), corners.end());
      all.push_back(corners);
    }
    std::sort(all.begin(), all.end());
    return all;
  };
  EXPECT_EQ(triangles(coned), triangles(solid));
  std::mt19937 random(7);
  const Eigen::Vector3d lo = solid.bbox_min(), hi = solid.bbox_max();
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  int inside = 0;
  for (int i = 0; i < 400; ++i) {
    const Eigen::Vector3d p =
        lo + (hi - lo).cwiseProduct(Eigen::Vector3d(unit(random), unit(random), unit(random)));
    auto in = [&](const TetMesh& mesh, double tolerance) {
      for (int t = 0; t < mesh.num_tets(); ++t) {
        if (InTet(mesh, t, p, tolerance)) return true;
      }
      return false;
    };
    // (a point within rounding of the surface may fall either way)
    if (in(solid, -1e-9) != in(solid, 1e-9)) continue;
    const bool in_solid = in(solid, 0.0);
    inside += in_solid;
    EXPECT_EQ(in(coned, 1e-12), in_solid) << p.transpose();
  }
  EXPECT_GT(inside, 100);
}

// A convex solid's surface coned to a point inside it (the made proxies of
// balls): one tetrahedron per surface triangle, the same solid; a surface
// not seen whole from the point (a torus's, from its centre) is an error.
TEST(Generators, ASurfaceConedToAPointFillsTheSameSolid) {
  for (const char* spec : {"sphere:size=0.05:res=3", "capsule:size=0.1,0.1:res=12",
                           "cylinder:size=0.1,0.02:res=6", "box:size=0.1,0.2,0.3:res=3,4,5"}) {
    SCOPED_TRACE(spec);
    const TetMesh solid = TetMesh::Build(MakeShape(spec));
    const TetMesh coned = TetMesh::Build(ConeToPoint(solid, Eigen::Vector3d(0.001, -0.002, 0.003)));
    EXPECT_EQ(coned.num_tets(), solid.surface().rows());
    EXPECT_EQ(coned.num_vertices(), static_cast<int>(solid.surface_vertices().size()) + 1);
    ExpectSameSolid(solid, coned);
  }
  const TetMesh torus = TetMesh::Build(MakeShape("torus:size=0.1,0.03:res=2"));
  try {
    ConeToPoint(torus, Eigen::Vector3d::Zero());
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("does not face away from the point"), std::string::npos)
        << e.what();
  }
}

// A capsule's or a cylinder's surface coned to its axis slab by slab (the
// made proxies of capsules and cylinders): the same solid, long or short,
// with no tetrahedron longer than a slab (its layers are 2 r / n thick; a
// capsule's caps, r); a mesh that is not such a body is an error: a
// torus's (its inner side faces the axis), a sphere's (its rings, taken
// below a "half-length" within it, are not a cylinder's: its slabs do not
// meet, and hold less than the sphere), one with no ring within the
// half-length.
TEST(Generators, ACapsulesOrCylindersSurfaceConedToItsAxisFillsTheSameSolid) {
  struct Case {
    const char* spec;
    double half_length;
    double longest;  // the longest a tetrahedron's edge may be
  };
  // (a slab's tet reaches from the axis to the side and across the slab:
  // sqrt(r^2 + (2 r / n)^2 + ...) <= sqrt(2) r for these; a cap's from its
  // point, r / 2 beyond the ring, to the cap's far end or the ring: r
  // sqrt(5) / 2 + ...)
  const Case cases[] = {
      {"capsule:size=0.1,0.1:res=12", 0.1, 0.15},      {"capsule:size=0.01,0.2:res=6", 0.2, 0.015},
      {"capsule:size=0.1,0.0001:res=4", 0.0001, 0.15}, {"cylinder:size=0.1,0.02:res=6", 0.02, 0.15},
      {"cylinder:size=0.02,0.3:res=5", 0.3, 0.03},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.spec);
    const TetMesh solid = TetMesh::Build(MakeShape(c.spec));
    const TetMesh coned = TetMesh::Build(ConeToAxis(solid, c.half_length));
    ExpectSameSolid(solid, coned);
    double longest = 0.0;
    for (Eigen::Index e = 0; e < coned.edges().rows(); ++e) {
      longest = std::max(longest, (coned.positions().row(coned.edges()(e, 0)) -
                                   coned.positions().row(coned.edges()(e, 1)))
                                      .norm());
    }
    EXPECT_LT(longest, c.longest);
  }
  struct Wrong {
    const char* spec;
    double half_length;
    const char* what;
  };
  const Wrong wrong[] = {
      {"torus:size=0.1,0.03:res=2", 0.049, "does not face away from the point it is coned to"},
      {"sphere:size=0.05:res=2", 0.049, "coned to its axis, it holds"},
      {"capsule:size=0.1,0.1:res=4", -1.0, "no rings along the axis within the half-length"},
  };
  for (const auto& [spec, half_length, what] : wrong) {
    SCOPED_TRACE(spec);
    const TetMesh mesh = TetMesh::Build(MakeShape(spec));
    try {
      ConeToAxis(mesh, half_length);
      ADD_FAILURE() << "no error";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(what), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("the mesh must be a cylinder's or a capsule's"),
                std::string::npos)
          << e.what();
    }
  }
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
