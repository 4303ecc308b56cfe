#include "collision/spatial_hash.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <random>

namespace tetcosim {
namespace {

TEST(SpatialHash, TableSizeIsAPrimeAboveTheItemCount) {
  SpatialHash hash;
  hash.Reset(0.1, 1000);
  EXPECT_GT(hash.table_size(), 1000);
  EXPECT_EQ(NextPrime(hash.table_size()), hash.table_size());
  EXPECT_EQ(NextPrime(90), 97);
  EXPECT_EQ(NextPrime(97), 97);
}

TEST(SpatialHash, BucketHoldsEveryItemOfItsCellAndTimeStampsForgetOldRounds) {
  SpatialHash hash;
  std::mt19937 rng(3);
  std::uniform_int_distribution<int> coordinate(-50, 50);
  std::vector<Eigen::Vector3i> cells(2000);
  for (auto& cell : cells) cell = {coordinate(rng), coordinate(rng), coordinate(rng)};
  for (int round = 0; round < 3; ++round) {
    hash.Reset(1.0, static_cast<int>(cells.size()));
    // each round inserts a different half of the items
    for (int i = round % 2; i < static_cast<int>(cells.size()); i += 2) hash.Insert(cells[i], i);
    hash.Build();
    for (int i = 0; i < static_cast<int>(cells.size()); ++i) {
      std::vector<int> found;
      hash.ForEach(cells[i], [&](int item) { found.push_back(item); });
      bool present = std::find(found.begin(), found.end(), i) != found.end();
      EXPECT_EQ(present, i % 2 == round % 2) << "item " << i << " round " << round;
      // everything found shares the bucket (cells may differ: hash collisions)
      for (int item : found) EXPECT_EQ(hash.Bucket(cells[item]), hash.Bucket(cells[i]));
    }
  }
}

TEST(SpatialHash, CellOfFloorsNegativeCoordinates) {
  SpatialHash hash;
  hash.Reset(0.5, 10);
  EXPECT_EQ(hash.CellOf({-0.1, 0.0, 0.49}), Eigen::Vector3i(-1, 0, 0));
  EXPECT_EQ(hash.CellOf({-0.5, 0.5, 1.0}), Eigen::Vector3i(-1, 1, 2));
}

}  // namespace
}  // namespace tetcosim

namespace tetcosim {
namespace {

TEST(SpatialHash, BucketIsTheHashModuloThePrimeTableSize) {
  SpatialHash hash;
  hash.Reset(1.0, 12345);
  std::mt19937 rng(5);
  std::uniform_int_distribution<int> coordinate(-100000, 100000);
  for (int i = 0; i < 10000; ++i) {
    Eigen::Vector3i c(coordinate(rng), coordinate(rng), coordinate(rng));
    std::uint32_t h = (static_cast<std::uint32_t>(c.x()) * 73856093u) ^
                      (static_cast<std::uint32_t>(c.y()) * 19349663u) ^
                      (static_cast<std::uint32_t>(c.z()) * 83492791u);
    ASSERT_EQ(hash.Bucket(c), static_cast<int>(h % static_cast<std::uint32_t>(hash.table_size())));
  }
}

}  // namespace
}  // namespace tetcosim
