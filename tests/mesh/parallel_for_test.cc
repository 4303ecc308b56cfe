#include "mesh/parallel_for.h"

#include <gtest/gtest.h>

#include <atomic>
#include <vector>

namespace tetcosim {
namespace {

// Every item of every group runs exactly once, whatever the threads, group
// sizes (empty ones, one holding everything), chunk, and whether the groups
// outnumber the threads or exceed kMaxGroups (then it is plain ParallelFor).
TEST(ParallelForGroups, RunsEveryItemExactlyOnce) {
  const std::vector<std::vector<int>> layouts = {
      {0, 0},                       // one empty group
      {0, 100},                     // one group
      {0, 50, 100},                 // even halves
      {0, 0, 97},                   // everything in the second group
      {0, 97, 97},                  // everything in the first
      {5, 6, 6, 40, 41},            // uneven, not starting at zero, an empty one
      {0, 3, 9, 27, 81, 243, 729},  // more groups than threads
  };
  std::vector<int> many(kMaxGroups + 2);
  for (size_t g = 0; g < many.size(); ++g) many[g] = static_cast<int>(3 * g);
  std::vector<std::vector<int>> all = layouts;
  all.push_back(many);
  for (const std::vector<int>& offsets : all) {
    for (int threads : {1, 2, 3}) {
      for (int chunk : {1, 4, 16}) {
        std::vector<std::atomic<int>> runs(offsets.back() + 1);
        ParallelForGroups(
            threads, offsets, [&](int i) { runs[i].fetch_add(1); }, chunk);
        for (int i = 0; i <= offsets.back(); ++i) {
          const int expected = i >= offsets.front() && i < offsets.back() ? 1 : 0;
          EXPECT_EQ(runs[i].load(), expected)
              << "item " << i << ", " << offsets.size() - 1 << " groups, " << threads
              << " threads, chunk " << chunk;
        }
      }
    }
  }
}

}  // namespace
}  // namespace tetcosim
