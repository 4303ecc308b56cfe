#include "mesh/vector_room.h"

#include <gtest/gtest.h>

#include <Eigen/Core>
#include <cstddef>
#include <cstdint>
#include <random>
#include <span>
#include <vector>

#include "mesh/same_bits.h"

namespace tetcosim {
namespace {

// A count that creeps up by one from 1 to 10,000 (contacts, step by step),
// each time assigned anew (std::vector's assign reallocates to exactly the
// count at every new high) or resized from empty: with room, the vector
// reallocates about log2(10,000) = 14 times. Shrinking keeps the room.
TEST(VectorRoom, ACountCreepingUpReallocatesLogarithmicallyOften) {
  for (const bool resize : {false, true}) {
    std::vector<int> v;
    int reallocations = 0;
    for (std::size_t n = 1; n <= 10000; ++n) {
      const std::size_t capacity = v.capacity();
      if (resize) {
        v.clear();  // (a step's count starts from nothing)
        ResizeWithRoom(v, n);
      } else {
        AssignWithRoom(v, n, 7);
      }
      ASSERT_EQ(v.size(), n);
      if (!resize) {
        ASSERT_EQ(v.back(), 7);
      }
      reallocations += v.capacity() != capacity;
    }
    EXPECT_LE(reallocations, 15) << (resize ? "resize" : "assign");
    const std::size_t capacity = v.capacity();
    AssignWithRoom(v, 10, 1);
    EXPECT_EQ(v.capacity(), capacity);
  }
}

// A size that goes up and down (the coupled step's degrees of freedom as
// rigid trees join and leave) keeps VectorXdWithRoom's storage: it moves
// only at a new high, about log2 times for a size creeping up to 10,000,
// and never on the way down or back up to an earlier high. What resize
// keeps and what a copy gives are its values.
TEST(VectorRoom, AnEigenVectorWithRoomReallocatesOnlyAtANewHigh) {
  VectorXdWithRoom v;
  EXPECT_EQ(v.size(), 0);
  int moves = 0;
  const double* data = v.data();
  for (Eigen::Index n = 1; n <= 10000; ++n) {
    v.resize(n);
    ASSERT_EQ(v.size(), n);
    moves += v.data() != data;
    data = v.data();
  }
  EXPECT_LE(moves, 15);
  for (const Eigen::Index n : {7, 9000, 0, 10000, 3, 10000}) {
    v.setZero(n);
    ASSERT_EQ(v.size(), n);
    EXPECT_EQ(v.data(), data) << "size " << n;
    EXPECT_EQ(v.squaredNorm(), 0.0);
  }
  v.resize(5);
  v << 1, 2, 3, 4, 5;
  v.resize(3);
  v.resize(5);
  EXPECT_EQ(v.head<3>(), Eigen::Vector3d(1, 2, 3)) << "kept through the sizes";
  v.resize(40000);  // (a new high: moved)
  EXPECT_NE(v.data(), data);
  EXPECT_EQ(v.head<3>(), Eigen::Vector3d(1, 2, 3)) << "kept through the move";
  v.resize(5);
  VectorXdWithRoom w;
  w = v;
  ASSERT_EQ(w.size(), 5);
  EXPECT_EQ(w.head<3>(), Eigen::Vector3d(1, 2, 3));
  const VectorXdWithRoom copy(v);
  ASSERT_EQ(copy.size(), 5);
  EXPECT_EQ(copy.head<3>(), Eigen::Vector3d(1, 2, 3));
  EXPECT_NE(copy.data(), v.data());
}

// Its arithmetic is Eigen::VectorXd's to the bit, and its storage is
// aligned as VectorXd's (which lets Eigen load it aligned). Random vectors
// of every size from 1 to 100: the dot product, the norm and an
// expression.
TEST(VectorRoom, AnEigenVectorWithRoomComputesAsVectorXdDoes) {
  std::mt19937_64 random(54);
  std::uniform_real_distribution<double> value(-1.0, 1.0);
  VectorXdWithRoom a, b, c;
  for (Eigen::Index n = 1; n <= 100; ++n) {
    Eigen::VectorXd x(n), y(n);
    for (Eigen::Index i = 0; i < n; ++i) {
      x[i] = value(random);
      y[i] = value(random);
    }
    a.resize(n);
    b.resize(n);
    c.resize(n);
    a = x;
    b = y;
    EXPECT_EQ(reinterpret_cast<std::uintptr_t>(a.data()) % EIGEN_MAX_ALIGN_BYTES, 0U);
    const double dot = x.dot(y), norm = x.norm();
    const double a_dot = a.dot(b), a_norm = a.norm();
    EXPECT_TRUE(SameBits({&dot, 1}, {&a_dot, 1})) << "size " << n;
    EXPECT_TRUE(SameBits({&norm, 1}, {&a_norm, 1})) << "size " << n;
    const Eigen::VectorXd z = x + 0.3 * y;
    c = a + 0.3 * b;
    const auto size = static_cast<std::size_t>(n);
    EXPECT_TRUE(SameBits({z.data(), size}, {c.data(), size})) << "size " << n;
  }
}

}  // namespace
}  // namespace tetcosim
