#include "collision/spatial_hash.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <random>
#include <tuple>

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

// BuildInsertions (all insertions at once: counted on one thread, sorted
// on 2 and 3, whatever their number) gives what Insert and Build give: the
// same entries in the same order, the same range for every cell; over
// rounds of different sizes (the time stamps), with keys, and with many
// items per cell.
TEST(SpatialHash, BuildInsertionsMatchesInsertAndBuild) {
  std::mt19937 rng(17);
  for (int n : {0, 1, 37, 5000, 30000}) {
    for (int spread : {3, 200}) {
      std::uniform_int_distribution<int> coordinate(-spread, spread);
      std::uniform_int_distribution<int> key(0, 3);
      std::vector<Eigen::Vector3i> cells(n);
      std::vector<int> keys(n);
      for (int i = 0; i < n; ++i) {
        cells[i] = {coordinate(rng), coordinate(rng), coordinate(rng)};
        keys[i] = key(rng);
      }
      SpatialHash expected;
      expected.Reset(0.1, n);
      for (int i = 0; i < n; ++i) expected.Insert(cells[i], 1000 + i, keys[i]);
      expected.Build();
      for (int threads : {1, 2, 3}) {
        SCOPED_TRACE(testing::Message()
                     << n << " items, spread " << spread << ", " << threads << " threads");
        SpatialHash sorted;
        for (int round = 0; round < 2; ++round) {  // (the second over the first's slots)
          sorted.Reset(0.1, n);
          sorted.ResizeInsertions(n);
          for (int i = n - 1; i >= 0; --i) sorted.SetInsertion(i, cells[i], 1000 + i, keys[i]);
          sorted.BuildInsertions(threads, /*min_sorted=*/0);
          ASSERT_EQ(sorted.table_size(), expected.table_size());
          ASSERT_EQ(sorted.num_items(), expected.num_items());
          EXPECT_TRUE(
              std::equal(sorted.items().begin(), sorted.items().end(), expected.items().begin()));
          for (int i = 0; i < n; ++i) {
            const SpatialHash::Range a = expected.Find(cells[i], keys[i]);
            const SpatialHash::Range b = sorted.Find(cells[i], keys[i]);
            ASSERT_EQ(std::tie(a.begin, a.end), std::tie(b.begin, b.end)) << "item " << i;
          }
          // cells of no item: the same (empty, or another cell's bucket)
          for (int k = 0; k < 20; ++k) {
            const Eigen::Vector3i cell(3 * spread + k, -k, 7);
            const SpatialHash::Range a = expected.Find(cell, k % 5);
            const SpatialHash::Range b = sorted.Find(cell, k % 5);
            EXPECT_EQ(std::tie(a.begin, a.end), std::tie(b.begin, b.end));
          }
        }
      }
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
