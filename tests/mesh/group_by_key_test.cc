#include "mesh/group_by_key.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <random>
#include <utility>

namespace tetcosim {
namespace {

TEST(GroupByKey, MatchesAStableSortByKey) {
  std::mt19937 rng(5);
  std::vector<int> offsets, values;
  // the same output vectors reused across sizes, including empty keys and
  // no pairs at all
  for (int num_pairs : {0, 1, 17, 1000}) {
    const int num_keys = 13;
    std::uniform_int_distribution<int> key(0, num_keys - 1);
    std::vector<std::pair<int, int>> pairs(num_pairs);
    for (int i = 0; i < num_pairs; ++i) pairs[i] = {key(rng), i * 7 % 101};
    GroupByKey(
        num_keys,
        [&](auto emit) {
          for (const auto& [k, v] : pairs) emit(k, v);
        },
        offsets, values);
    std::vector<std::pair<int, int>> sorted = pairs;
    std::stable_sort(sorted.begin(), sorted.end(),
                     [](const auto& a, const auto& b) { return a.first < b.first; });
    ASSERT_EQ(offsets.size(), static_cast<size_t>(num_keys + 1));
    ASSERT_EQ(values.size(), pairs.size());
    EXPECT_EQ(offsets[0], 0);
    for (int k = 0; k < num_keys; ++k) {
      for (int i = offsets[k]; i < offsets[k + 1]; ++i) {
        EXPECT_EQ(sorted[i].first, k) << "row " << k;
        EXPECT_EQ(values[i], sorted[i].second) << "row " << k;
      }
    }
  }
}

}  // namespace
}  // namespace tetcosim
