#include "collision/geometry.h"

#include <gtest/gtest.h>

#include <limits>
#include <random>

namespace tetcosim {
namespace {

Eigen::Vector3d RandomPoint(std::mt19937& rng) {
  std::uniform_real_distribution<double> coordinate(-1.0, 1.0);
  return {coordinate(rng), coordinate(rng), coordinate(rng)};
}

TEST(TetCoordinates, ReproduceThePointAndSumToOne) {
  std::mt19937 rng(7);
  for (int trial = 0; trial < 1000; ++trial) {
    Eigen::Vector3d corner[4];
    for (Eigen::Vector3d& c : corner) c = RandomPoint(rng);
    const TetCoordinates coordinates(corner[0], corner[1], corner[2], corner[3]);
    ASSERT_FALSE(coordinates.degenerate());
    const double volume =
        std::abs(
            (corner[1] - corner[0]).dot((corner[2] - corner[0]).cross(corner[3] - corner[0]))) /
        6.0;
    if (volume < 1e-3) continue;  // ill-conditioned: the identity holds less tightly
    const Eigen::Vector3d p = RandomPoint(rng);
    const Eigen::Vector4d l = coordinates(p);
    Eigen::Vector3d back = Eigen::Vector3d::Zero();
    for (int i = 0; i < 4; ++i) back += l[i] * corner[i];
    EXPECT_NEAR((back - p).norm(), 0.0, 1e-11) << "trial " << trial;
    EXPECT_NEAR(l.sum(), 1.0, 1e-12);
    // the same through TetBarycentric, bit for bit
    Eigen::Vector4d l2;
    ASSERT_TRUE(TetBarycentric(corner[0], corner[1], corner[2], corner[3], p, l2));
    EXPECT_EQ(l, l2);
  }
}

TEST(TetCoordinates, CornersAreUnitVectors) {
  const Eigen::Vector3d corner[4] = {
      {0.1, 0.2, 0.3}, {1.1, 0.2, 0.3}, {0.1, 1.7, 0.3}, {0.1, 0.2, -0.9}};
  const TetCoordinates coordinates(corner[0], corner[1], corner[2], corner[3]);
  for (int i = 0; i < 4; ++i) {
    const Eigen::Vector4d l = coordinates(corner[i]);
    for (int j = 0; j < 4; ++j) EXPECT_NEAR(l[j], i == j ? 1.0 : 0.0, 1e-15);
  }
}

TEST(TetCoordinates, FlatAndNonFiniteTetrahedraAreDegenerate) {
  const Eigen::Vector3d a(0, 0, 0), b(1, 0, 0), c(0, 1, 0);
  EXPECT_TRUE(TetCoordinates(a, b, c, Eigen::Vector3d(0.3, 0.3, 0.0)).degenerate());
  const double inf = std::numeric_limits<double>::infinity();
  EXPECT_TRUE(TetCoordinates(a, b, c, Eigen::Vector3d(0, 0, inf)).degenerate());
  Eigen::Vector4d l;
  EXPECT_FALSE(TetBarycentric(a, b, c, Eigen::Vector3d(0.3, 0.3, 0.0), a, l));
}

TEST(SegmentTriangle, CrossingLiesOnTheSegmentAndTheTriangle) {
  std::mt19937 rng(11);
  int crossings = 0;
  for (int trial = 0; trial < 2000; ++trial) {
    const Eigen::Vector3d q = RandomPoint(rng), p = RandomPoint(rng);
    const Eigen::Vector3d a = RandomPoint(rng), b = RandomPoint(rng), c = RandomPoint(rng);
    double t, u, v;
    if (!SegmentTriangle(q, p, a, b, c, t, u, v)) continue;
    ++crossings;
    EXPECT_GE(t, -1e-12);
    EXPECT_LE(t, 1.0 + 1e-12);
    EXPECT_GE(u, -1e-12);
    EXPECT_GE(v, -1e-12);
    EXPECT_LE(u + v, 1.0 + 1e-12);
    const Eigen::Vector3d on_segment = q + t * (p - q);
    const Eigen::Vector3d on_triangle = (1.0 - u - v) * a + u * b + v * c;
    EXPECT_NEAR((on_segment - on_triangle).norm(), 0.0, 1e-9) << "trial " << trial;
  }
  EXPECT_GT(crossings, 50);  // the test saw crossings at all
}

TEST(SmoothNormal, InterpolatesTheVertexNormals) {
  std::mt19937 rng(13);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  for (int trial = 0; trial < 200; ++trial) {
    const Eigen::Vector3d n0 = RandomPoint(rng).normalized(), n1 = RandomPoint(rng).normalized(),
                          n2 = RandomPoint(rng).normalized();
    const double u = 0.5 * unit(rng), v = 0.5 * unit(rng);
    const Eigen::Vector3d sum = (1.0 - u - v) * n0 + u * n1 + v * n2;
    if (sum.norm() < 1e-3) continue;
    int face_calls = 0;
    Eigen::Vector3d normal;
    ASSERT_TRUE(SmoothNormal(
        n0, n1, n2, u, v, [&] { return ++face_calls, Eigen::Vector3d(0, 0, 1); }, normal));
    EXPECT_NEAR((normal - sum.normalized()).norm(), 0.0, 1e-15) << "trial " << trial;
    EXPECT_EQ(face_calls, 0);  // the face normal only where the interpolation cancels
  }
  // at a vertex: that vertex's normal
  const Eigen::Vector3d n0(0, 0, 1), n1(1, 0, 0), n2(0, 1, 0);
  Eigen::Vector3d normal;
  ASSERT_TRUE(SmoothNormal(
      n0, n1, n2, 0.0, 1.0, [] { return Eigen::Vector3d(1, 1, 1); }, normal));
  EXPECT_EQ(normal, n2);
}

// Opposite vertex normals (a fold, a crushed tetrahedron) cancel halfway
// between their vertices: the face normal there, normalised; nearly
// opposite ones still interpolate.
TEST(SmoothNormal, CancellingVertexNormalsGiveTheFaceNormal) {
  const Eigen::Vector3d up(0, 0, 1), side(0, 1, 0);
  const Eigen::Vector3d e1(2, 0, 0), e2(0, 3, 0);  // face normal e1 x e2 = (0, 0, 6)
  Eigen::Vector3d normal;
  ASSERT_TRUE(SmoothNormal(
      up, -up, side, 0.5, 0.0, [&]() -> Eigen::Vector3d { return e1.cross(e2); }, normal));
  EXPECT_EQ(normal, Eigen::Vector3d(0, 0, 1));
  // all three cancel at (1/3, 1/3, 1/3)
  const Eigen::Vector3d a(1, 0, 0), b(-0.5, std::sqrt(0.75), 0), c(-0.5, -std::sqrt(0.75), 0);
  const double third = 1.0 / 3.0;
  ASSERT_TRUE(SmoothNormal(
      a, b, c, third, third, [&]() -> Eigen::Vector3d { return -e1.cross(e2); }, normal));
  EXPECT_NEAR((normal - Eigen::Vector3d(0, 0, -1)).norm(), 0.0, 1e-15);
  // nearly opposite: a short sum with a direction of its own
  const Eigen::Vector3d tilted = Eigen::Vector3d(1e-6, 0, -1).normalized();
  ASSERT_TRUE(SmoothNormal(
      up, tilted, side, 0.5, 0.0, [&]() -> Eigen::Vector3d { return e1.cross(e2); }, normal));
  EXPECT_NEAR((normal - Eigen::Vector3d(1, 0, 0)).norm(), 0.0, 1e-6);
  // a degenerate face under cancelling normals: no normal
  EXPECT_FALSE(SmoothNormal(
      up, -up, side, 0.5, 0.0, [] { return Eigen::Vector3d::Zero(); }, normal));
}

}  // namespace
}  // namespace tetcosim
