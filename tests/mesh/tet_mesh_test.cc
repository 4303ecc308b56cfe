#include "mesh/tet_mesh.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <set>
#include <utility>
#include <vector>

#include "mesh/error.h"
#include "mesh/generators.h"
#include "tests/support/mesh_checks.h"

namespace tetcosim {
namespace {

RawMesh UnitTet() {
  RawMesh raw;
  raw.source = "unit-tet";
  raw.positions.resize(4, 3);
  raw.positions << 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1;
  raw.tets.resize(1, 4);
  raw.tets << 0, 1, 2, 3;
  return raw;
}

TEST(TetMesh, SingleTetrahedronDerivedData) {
  TetMesh mesh = TetMesh::Build(UnitTet());
  EXPECT_EQ(mesh.num_vertices(), 4);
  EXPECT_EQ(mesh.surface().rows(), 4);
  EXPECT_EQ(mesh.edges().rows(), 6);
  EXPECT_DOUBLE_EQ(mesh.total_volume(), 1.0 / 6.0);
  EXPECT_EQ(mesh.surface_vertices().size(), 4u);
  // every surface triangle's normal points away from the centroid
  Eigen::Vector3d centroid = mesh.positions().colwise().mean().transpose();
  for (Eigen::Index f = 0; f < 4; ++f) {
    Eigen::Vector3d a = mesh.positions().row(mesh.surface()(f, 0));
    Eigen::Vector3d b = mesh.positions().row(mesh.surface()(f, 1));
    Eigen::Vector3d c = mesh.positions().row(mesh.surface()(f, 2));
    EXPECT_GT((b - a).cross(c - a).dot((a + b + c) / 3.0 - centroid), 0.0);
  }
  // every vertex of a tetrahedron is adjacent to the three others
  for (int v = 0; v < 4; ++v) {
    EXPECT_EQ(mesh.adjacency_offsets()[v + 1] - mesh.adjacency_offsets()[v], 3);
  }
  // area-weighted normal at the origin: the three coordinate faces have equal
  // area, so it points along -(1, 1, 1)
  EXPECT_TRUE(mesh.vertex_normals().row(0).isApprox(-Eigen::RowVector3d::Ones().normalized()));
  EXPECT_EQ(mesh.bbox_min(), Eigen::Vector3d::Zero());
  EXPECT_EQ(mesh.bbox_max(), Eigen::Vector3d::Ones());
  EXPECT_NEAR(mesh.average_edge_length(), (3.0 + 3.0 * std::sqrt(2.0)) / 6.0, 1e-15);
}

TEST(TetMesh, InvertedTetrahedraAreFlippedOrRejected) {
  RawMesh raw = UnitTet();
  raw.tets << 0, 2, 1, 3;  // negative volume
  TetMesh mesh = TetMesh::Build(raw);
  EXPECT_EQ(mesh.num_flipped(), 1);
  EXPECT_GT(mesh.rest_volumes()[0], 0.0);
  ASSERT_EQ(mesh.warnings().size(), 1u);
  EXPECT_NE(mesh.warnings()[0].find("flipped"), std::string::npos);
  TetMeshOptions strict;
  strict.flip_inverted = false;
  EXPECT_THROW(TetMesh::Build(raw, strict), Error);
}

// A mesh past the size limit is refused with a message, before any count
// made from its size could overflow an int; one at the limit is not
// refused for its size (its tetrahedra, all alike, fail a later check).
TEST(TetMesh, MeshesPastTheSizeLimitAreRefused) {
  for (const int extra : {1, 0}) {
    RawMesh raw = UnitTet();
    raw.tets = Tets::Zero(TetMesh::kMaxTets + extra, 4);
    try {
      TetMesh::Build(std::move(raw));
      ADD_FAILURE() << "a mesh of " << TetMesh::kMaxTets + extra << " tetrahedra was built";
    } catch (const Error& e) {
      const std::string message = e.what();
      EXPECT_EQ(message.find("at most") != std::string::npos, extra == 1) << message;
    }
  }
}

TEST(TetMesh, UnreferencedVerticesAreDroppedWithAWarning) {
  RawMesh raw = UnitTet();
  raw.positions.conservativeResize(6, 3);
  raw.positions.row(4) << 5, 5, 5;
  raw.positions.row(5) = raw.positions.row(3);
  raw.positions.row(3) << 9, 9, 9;
  raw.tets << 0, 1, 2, 5;
  raw.node_ids = {10, 11, 12, 13, 14, 15};
  TetMesh mesh = TetMesh::Build(raw);
  EXPECT_EQ(mesh.num_vertices(), 4);
  EXPECT_DOUBLE_EQ(mesh.total_volume(), 1.0 / 6.0);
  EXPECT_EQ(mesh.node_ids(), (std::vector<long>{10, 11, 12, 15}));
  ASSERT_EQ(mesh.warnings().size(), 1u);
  EXPECT_NE(mesh.warnings()[0].find("2 vertices"), std::string::npos);
}

TEST(TetMesh, AdjacencyMatchesEdgesAndIsSymmetric) {
  TetMesh mesh = TetMesh::Build(MakeShape("torus:size=0.1,0.03:res=2"));
  const auto& offsets = mesh.adjacency_offsets();
  const auto& adjacency = mesh.adjacency();
  EXPECT_EQ(adjacency.size(), 2 * static_cast<size_t>(mesh.edges().rows()));
  auto adjacent = [&](int a, int b) {
    return std::binary_search(adjacency.begin() + offsets[a], adjacency.begin() + offsets[a + 1],
                              b);
  };
  for (Eigen::Index e = 0; e < mesh.edges().rows(); ++e) {
    EXPECT_TRUE(adjacent(mesh.edges()(e, 0), mesh.edges()(e, 1)));
    EXPECT_TRUE(adjacent(mesh.edges()(e, 1), mesh.edges()(e, 0)));
  }
  // the most neighbours of a vertex, counted from the edges
  std::vector<int> degree(mesh.num_vertices(), 0);
  int most = 0;
  for (Eigen::Index e = 0; e < mesh.edges().rows(); ++e) {
    for (int k = 0; k < 2; ++k) most = std::max(most, ++degree[mesh.edges()(e, k)]);
  }
  EXPECT_GT(most, 4);
  EXPECT_EQ(mesh.max_degree(), most);
  // vertex-tet incidence lists each tetrahedron at its four vertices
  for (int v = 0; v < mesh.num_vertices(); ++v) {
    for (int i = mesh.vertex_tet_offsets()[v]; i < mesh.vertex_tet_offsets()[v + 1]; ++i) {
      auto tet = mesh.tets().row(mesh.vertex_tets()[i]);
      EXPECT_TRUE((tet.array() == v).any());
    }
  }
}

TEST(TetMesh, SphereNormalsAreRadialAndInteriorNormalsZero) {
  TetMesh mesh = TetMesh::Build(MakeShape("sphere:size=1:res=2"));
  for (int v = 0; v < mesh.num_vertices(); ++v) {
    Eigen::RowVector3d n = mesh.vertex_normals().row(v);
    if (mesh.is_surface_vertex(v)) {
      EXPECT_NEAR(n.norm(), 1.0, 1e-12);
      EXPECT_GT(n.dot(mesh.positions().row(v).normalized()), 0.99);
    } else {
      EXPECT_EQ(n.norm(), 0.0);
    }
  }
}

TEST(TetMesh, VertexNormalIsTheFullComputationsRowBitForBit) {
  // a deformed capsule: every vertex's normal from its own triangles equals
  // the one ComputeVertexNormals gets from all of them, exactly; and each
  // vertex's triangle list holds exactly the triangles that have it
  TetMesh mesh = TetMesh::Build(MakeShape("capsule:size=0.05,0.1:res=3"));
  Positions x = mesh.positions();
  for (Eigen::Index v = 0; v < x.rows(); ++v) {
    x(v, 0) += 0.3 * std::sin(7.0 * x(v, 2)) * x(v, 1);
    x(v, 2) *= 1.0 + 0.2 * x(v, 0);
  }
  Positions normals;
  ComputeVertexNormals(x, mesh.surface(), normals);
  int listed = 0;
  for (int v = 0; v < mesh.num_vertices(); ++v) {
    Eigen::Vector3d n = VertexNormal(mesh, x, v);
    for (int k = 0; k < 3; ++k) ASSERT_EQ(n[k], normals(v, k)) << "vertex " << v;
    const auto& offsets = mesh.vertex_triangle_offsets();
    for (int i = offsets[v]; i < offsets[v + 1]; ++i) {
      EXPECT_TRUE((mesh.surface().row(mesh.vertex_triangles()[i]).array() == v).any());
      if (i > offsets[v]) {
        EXPECT_LT(mesh.vertex_triangles()[i - 1], mesh.vertex_triangles()[i]);
      }
    }
    listed += offsets[v + 1] - offsets[v];
  }
  EXPECT_EQ(listed, 3 * mesh.surface().rows());
}

// the mean volume of the bounding boxes of runs of TetMesh::kSpatialRun
// consecutive tets
double MeanRunBoxVolume(const TetMesh& mesh, const std::vector<int>& order) {
  constexpr size_t kRun = TetMesh::kSpatialRun;
  double sum = 0.0;
  int runs = 0;
  for (size_t begin = 0; begin < order.size(); begin += kRun, ++runs) {
    Eigen::Vector3d lo = Eigen::Vector3d::Constant(1e300), hi = -lo;
    for (size_t i = begin; i < std::min(order.size(), begin + kRun); ++i) {
      for (int k = 0; k < 4; ++k) {
        lo = lo.cwiseMin(mesh.positions().row(mesh.tets()(order[i], k)).transpose());
        hi = hi.cwiseMax(mesh.positions().row(mesh.tets()(order[i], k)).transpose());
      }
    }
    sum += (hi - lo).prod();
  }
  return sum / runs;
}

TEST(TetMesh, SpatialTetOrderIsAPermutationWithCompactRuns) {
  RawMesh raw = MakeShape("box:size=0.1,0.1,0.1:res=8,8,8");
  const TetMesh generated = TetMesh::Build(raw);
  // the same tets in a random order (as a mesher writes them)
  std::vector<int> shuffle(raw.tets.rows());
  for (size_t t = 0; t < shuffle.size(); ++t) shuffle[t] = static_cast<int>(t);
  std::mt19937 rng(3);
  std::shuffle(shuffle.begin(), shuffle.end(), rng);
  RawMesh shuffled_raw = raw;
  for (size_t t = 0; t < shuffle.size(); ++t) shuffled_raw.tets.row(t) = raw.tets.row(shuffle[t]);
  const TetMesh shuffled = TetMesh::Build(shuffled_raw);
  for (const TetMesh* mesh : {&generated, &shuffled}) {
    std::vector<int> sorted = mesh->spatial_tet_order();
    std::sort(sorted.begin(), sorted.end());
    for (int t = 0; t < mesh->num_tets(); ++t) ASSERT_EQ(sorted[t], t);
  }
  std::vector<int> file_order(shuffle.size());
  for (size_t t = 0; t < file_order.size(); ++t) file_order[t] = static_cast<int>(t);
  // the shuffled file's runs span most of the box; the spatial order's are
  // about as compact as the generator's own cell-by-cell order
  const double cube = std::pow(0.2, 3);
  EXPECT_GT(MeanRunBoxVolume(shuffled, file_order), 0.3 * cube);
  const double spatial = MeanRunBoxVolume(shuffled, shuffled.spatial_tet_order());
  EXPECT_LT(spatial, 0.02 * cube);
  EXPECT_LT(spatial, 2.0 * MeanRunBoxVolume(generated, file_order));
  // the generator's order is kept when it is compact enough
  EXPECT_LE(MeanRunBoxVolume(generated, generated.spatial_tet_order()),
            MeanRunBoxVolume(generated, file_order) * (1.0 + 1e-12));
}

// Each run of the spatial order lists the vertices of its tets, each once:
// max(1, #T / kSpatialRun) runs, the last to the end (fewer tets than a
// run, a remainder, a whole number of runs).
TEST(TetMesh, SpatialRunsListTheirTetsVertices) {
  for (const char* spec : {"box:size=0.1:res=1", "sphere:size=0.05:res=0", "box:size=0.1:res=3",
                           "box:size=0.1:res=4", "torus:size=0.06,0.025:res=2"}) {
    SCOPED_TRACE(spec);
    const TetMesh mesh = TetMesh::Build(MakeShape(spec));
    const int num_runs = std::max(1, mesh.num_tets() / TetMesh::kSpatialRun);
    ASSERT_EQ(mesh.num_spatial_runs(), num_runs);
    const std::vector<int>& offsets = mesh.spatial_run_vertex_offsets();
    for (int r = 0; r < num_runs; ++r) {
      std::set<int> expected;
      const int end = r + 1 == num_runs ? mesh.num_tets() : TetMesh::kSpatialRun * (r + 1);
      for (int n = TetMesh::kSpatialRun * r; n < end; ++n) {
        for (int k = 0; k < 4; ++k) expected.insert(mesh.tets()(mesh.spatial_tet_order()[n], k));
      }
      const std::vector<int> listed(mesh.spatial_run_vertices().begin() + offsets[r],
                                    mesh.spatial_run_vertices().begin() + offsets[r + 1]);
      EXPECT_EQ(listed, std::vector<int>(expected.begin(), expected.end())) << "run " << r;
    }
  }
}

TEST(TetMesh, SurfaceTetOwnsItsTriangle) {
  TetMesh mesh = TetMesh::Build(MakeShape("capsule:size=0.1,0.1:res=3"));
  for (Eigen::Index f = 0; f < mesh.surface().rows(); ++f) {
    auto tet = mesh.tets().row(mesh.surface_tet()[f]);
    for (int k = 0; k < 3; ++k) EXPECT_TRUE((tet.array() == mesh.surface()(f, k)).any());
  }
}

}  // namespace
}  // namespace tetcosim
