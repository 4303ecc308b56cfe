#include "collision/surfaces.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "collision/geometry.h"
#include "mesh/generators.h"
#include "mesh/same_bits.h"
#include "tests/collision/scene_helpers.h"

namespace tetcosim {
namespace {

using testing::Pose;
using testing::TestScene;

// The sides of the box [lo, hi] that p lies beyond, one bit each.
std::uint8_t Outcode(const Eigen::Vector3d& p, const Eigen::Vector3d& lo,
                     const Eigen::Vector3d& hi) {
  std::uint8_t code = 0;
  for (int k = 0; k < 3; ++k) {
    code |= static_cast<std::uint8_t>((p[k] < lo[k]) << (2 * k));
    code |= static_cast<std::uint8_t>((p[k] > hi[k]) << (2 * k + 1));
  }
  return code;
}

// A deformed body (a box, a sphere; a sphere of 20 faces is small), a
// search box over part of it, and the surfaces made of it, checked against
// brute force over its faces:
// - the entries in play are exactly the faces whose corners do not all lie
//   beyond one side of the search box, each with its corners, edges and a
//   box around them; AddRemaining adds the others, once;
// - every entry whose box meets a query box is in the hash buckets of the
//   query's cells or in the listed large entries (what stage 2 relies on);
// - the normals of the entries' vertices are VertexNormal's, bit for bit;
// - a small body's groups hold every face, lanes past the last NaN.
TEST(Surfaces, MatchBruteForce) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> jitter(-0.002, 0.002);
  // (a bipyramid's 6 faces leave two lanes of its second group empty)
  for (const std::string spec : {"box:size=0.1,0.06,0.04:res=10,6,4", "sphere:size=0.05:res=3",
                                 "sphere:size=0.05:res=1", "bipyramid"}) {
    for (auto [cell_size, coverage] :
         {std::pair{0.004, 0.4}, {0.01, 0.5}, {0.05, 0.6}, {0.01, 1.2}}) {
      // (coverage: of the body's extent by the search box; from 1, every
      // face is in play and the normals are computed for every vertex)
      SCOPED_TRACE(spec + ", cell " + std::to_string(cell_size) + ", coverage " +
                   std::to_string(coverage));
      TestScene scene;
      scene.Add(
          TetMesh::Build(spec == "bipyramid" ? testing::Bipyramid(0.03, 0.04) : MakeShape(spec)),
          Pose({0, 0, 0}, 0.3, {1, 2, 3}));
      Positions& x = *scene.positions[0];
      for (Eigen::Index v = 0; v < x.rows(); ++v) {
        x.row(v) += Eigen::RowVector3d(jitter(rng), jitter(rng), jitter(rng));
      }
      const TetMesh& mesh = *scene.meshes[0];
      const Triangles& surface = mesh.surface();
      const int num_faces = static_cast<int>(surface.rows());
      // a search box over a corner of the body
      const Eigen::Vector3d lo = x.colwise().minCoeff().transpose();
      const Eigen::Vector3d hi = lo + coverage * (x.colwise().maxCoeff().transpose() - lo);
      std::vector<std::uint8_t> outcode(x.rows());
      for (Eigen::Index v = 0; v < x.rows(); ++v) outcode[v] = Outcode(x.row(v), lo, hi);
      std::set<int> in_play;
      for (int f = 0; f < num_faces; ++f) {
        if ((outcode[surface(f, 0)] & outcode[surface(f, 1)] & outcode[surface(f, 2)]) == 0) {
          in_play.insert(f);
        }
      }
      ASSERT_FALSE(in_play.empty());
      const bool small = num_faces <= Surfaces::kSmallSurface;
      if (coverage > 1.0) {
        EXPECT_EQ(static_cast<int>(in_play.size()), num_faces);
      } else if (!small) {
        EXPECT_LT(static_cast<int>(in_play.size()), num_faces);
      }

      Surfaces surfaces;
      const std::vector<KeptObject> kept(1);
      const std::vector<int> list = {0};
      std::vector<int> faces;
      surfaces.Place(scene.objects, list, kept, /*full=*/false, /*hash_and_normals=*/true,
                     cell_size);
      surfaces.Make(scene.objects, 0, kept[0], outcode.data(), faces);
      EXPECT_EQ(surfaces.small(0), small);
      const int begin = surfaces.entry_begin(0);
      const int end = surfaces.entry_end(0);
      if (small) {  // every face, in its group's lane
        ASSERT_EQ(end - begin, num_faces);
        const Surfaces::SmallGroup* groups = surfaces.groups(0);
        for (int f = 0; f < (num_faces + 3) / 4 * 4; ++f) {
          const Surfaces::SmallGroup& group = groups[f / 4];
          for (int k = 0; k < 3; ++k) {
            if (f >= num_faces) {
              EXPECT_TRUE(std::isnan(group.lo[k][f % 4]) && std::isnan(group.hi[k][f % 4]));
              continue;
            }
            EXPECT_EQ(group.corner[k][f % 4], x(surface(f, 0), k)) << f;
            EXPECT_EQ(group.edge0[k][f % 4], x(surface(f, 1), k) - x(surface(f, 0), k)) << f;
            EXPECT_EQ(group.edge1[k][f % 4], x(surface(f, 2), k) - x(surface(f, 0), k)) << f;
            for (int c = 0; c < 3; ++c) {
              EXPECT_LE(group.lo[k][f % 4], x(surface(f, c), k));
              EXPECT_GE(group.hi[k][f % 4], x(surface(f, c), k));
            }
          }
        }
        continue;
      }
      std::set<int> made;
      for (int index = begin; index < end; ++index) {
        const Surfaces::Entry& entry = surfaces.entry(index);
        const Surfaces::Geometry& geometry = surfaces.geometry(index);
        EXPECT_EQ(entry.object, 0);
        EXPECT_TRUE(made.insert(entry.face).second) << "face " << entry.face << " twice";
        for (int c = 0; c < 3; ++c) {
          const Eigen::Vector3d corner = x.row(surface(entry.face, c)).transpose();
          EXPECT_EQ(geometry.corner[c], corner);
          EXPECT_TRUE((entry.lo.array() <= corner.array()).all());
          EXPECT_TRUE((corner.array() <= entry.hi.array()).all());
        }
        EXPECT_EQ(geometry.edge[0], geometry.corner[1] - geometry.corner[0]);
        EXPECT_EQ(geometry.edge[1], geometry.corner[2] - geometry.corner[0]);
        // the normals stage 2 reads at a crossing of this face
        for (int c = 0; c < 3; ++c) {
          const int v = surface(entry.face, c);
          const Eigen::Vector3d expected = VertexNormal(mesh, x, v);
          const Eigen::Vector3d normal = surfaces.normals(0).row(v).transpose();
          EXPECT_TRUE(SameBits({normal.data(), 3}, {expected.data(), 3})) << "vertex " << v;
        }
      }
      EXPECT_EQ(made, in_play);
      // queries: boxes of random segments over the body
      const Surfaces::Table& table = surfaces.table(0);
      std::uniform_int_distribution<int> vertex(0, static_cast<int>(x.rows()) - 1);
      for (int q = 0; q < 200; ++q) {
        const Eigen::Vector3d a = x.row(vertex(rng)).transpose();
        const Eigen::Vector3d b =
            a + 0.01 * Eigen::Vector3d(jitter(rng), jitter(rng), jitter(rng)) / 0.002;
        const Eigen::Vector3d query_lo = a.cwiseMin(b), query_hi = a.cwiseMax(b);
        std::set<int> found(table.large.begin(), table.large.end());
        const Eigen::Vector3i from = GridCell(query_lo, 1.0 / cell_size);
        const Eigen::Vector3i to = GridCell(query_hi, 1.0 / cell_size);
        table.hash.ForEachBucket(from, to, 0, [&](SpatialHash::Range range) {
          for (int e = range.begin; e < range.end; ++e) found.insert(table.hash.items()[e]);
        });
        for (int index = begin; index < end; ++index) {
          const Surfaces::Entry& entry = surfaces.entry(index);
          if (BoxesOverlap(entry.lo, entry.hi, query_lo, query_hi)) {
            EXPECT_TRUE(found.count(index)) << "entry " << index << ", query " << q;
          }
        }
      }
      // the rest, for closest features
      surfaces.AddRemaining(scene.objects, 0, kept[0], outcode.data());
      std::set<int> all = made;
      for (int index = surfaces.rest_begin(0); index < surfaces.rest_end(0); ++index) {
        EXPECT_TRUE(all.insert(surfaces.entry(index).face).second);
      }
      EXPECT_EQ(static_cast<int>(all.size()), num_faces);
      surfaces.AddRemaining(scene.objects, 0, kept[0], outcode.data());  // (once: no more)
      EXPECT_EQ(surfaces.num_entries(), surfaces.rest_end(0));
    }
  }
}

}  // namespace
}  // namespace tetcosim
