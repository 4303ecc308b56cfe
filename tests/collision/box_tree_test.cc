#include "collision/box_tree.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <limits>
#include <random>
#include <vector>

namespace tetcosim {
namespace {

double BoxDistance2(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi,
                    const Eigen::Vector3d& p) {
  return (lo - p).cwiseMax(p - hi).cwiseMax(0.0).squaredNorm();
}

struct Boxes {
  std::vector<Eigen::Vector3d> lo, hi;
};

// n boxes of random size in the unit cube; with `same_centre`, all around
// one point (every split ties)
Boxes RandomBoxes(int n, std::mt19937& rng, bool same_centre) {
  std::uniform_real_distribution<double> coordinate(0.0, 1.0), size(0.0, 0.05);
  Boxes boxes;
  for (int i = 0; i < n; ++i) {
    Eigen::Vector3d centre(0.5, 0.5, 0.5);
    if (!same_centre) centre = {coordinate(rng), coordinate(rng), coordinate(rng)};
    Eigen::Vector3d half(size(rng), size(rng), size(rng));
    boxes.lo.push_back(centre - half);
    boxes.hi.push_back(centre + half);
  }
  return boxes;
}

// The nearest box by the tree (each visited item's exact distance lowers
// the bound) against brute force over every box, for points inside and
// far outside the boxes' region; and the tree never visits an item twice
// or an item farther than the bound at that moment.
TEST(BoxTree, NearestMatchesBruteForce) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> query(-1.0, 2.0);
  for (int n : {0, 1, 3, 4, 5, 17, 100, 1000}) {
    for (bool same_centre : {false, true}) {
      const Boxes boxes = RandomBoxes(n, rng, same_centre);
      BoxTree tree;
      tree.Build(boxes.lo, boxes.hi);
      ASSERT_EQ(tree.num_items(), n);
      for (int q = 0; q < 200; ++q) {
        const Eigen::Vector3d p(query(rng), query(rng), query(rng));
        double expected = std::numeric_limits<double>::infinity();
        for (int i = 0; i < n; ++i) {
          expected = std::min(expected, BoxDistance2(boxes.lo[i], boxes.hi[i], p));
        }
        double best = std::numeric_limits<double>::infinity();
        std::vector<int> visits(n, 0);
        tree.Nearest(p, best, [&](int item) {
          ASSERT_GE(item, 0);
          ASSERT_LT(item, n);
          ++visits[item];
          const double d = BoxDistance2(boxes.lo[item], boxes.hi[item], p);
          EXPECT_LE(d, best);
          best = std::min(best, d);
        });
        EXPECT_EQ(best, expected) << "n " << n << " query " << q;
        for (int v : visits) EXPECT_LE(v, 1);
      }
    }
  }
}

// The boxes meeting a query box, by the tree and by testing every box:
// the same set, each item once (closed boxes: touching counts).
TEST(BoxTree, OverlappingMatchesBruteForce) {
  std::mt19937 rng(13);
  std::uniform_real_distribution<double> corner(-0.2, 1.2), size(0.0, 0.3);
  for (int n : {0, 1, 5, 64, 1000}) {
    for (bool same_centre : {false, true}) {
      const Boxes boxes = RandomBoxes(n, rng, same_centre);
      BoxTree tree;
      tree.Build(boxes.lo, boxes.hi);
      for (int q = 0; q < 200; ++q) {
        Eigen::Vector3d lo(corner(rng), corner(rng), corner(rng));
        Eigen::Vector3d hi = lo + Eigen::Vector3d(size(rng), size(rng), size(rng));
        if (q == 0 && n > 0) hi = lo = boxes.hi[0];  // a point on a box's corner
        std::vector<int> expected, found;
        for (int i = 0; i < n; ++i) {
          if ((boxes.lo[i].array() <= hi.array()).all() &&
              (lo.array() <= boxes.hi[i].array()).all()) {
            expected.push_back(i);
          }
        }
        tree.Overlapping(lo, hi, [&](int item) { found.push_back(item); });
        std::sort(found.begin(), found.end());
        EXPECT_EQ(found, expected) << "n " << n << " query " << q;
      }
    }
  }
}

// A bound passed in prunes: nothing farther than it is visited, and a
// bound below every box visits nothing.
TEST(BoxTree, StartingBoundPrunes) {
  std::mt19937 rng(9);
  const Boxes boxes = RandomBoxes(500, rng, false);
  BoxTree tree;
  tree.Build(boxes.lo, boxes.hi);
  const Eigen::Vector3d p(3.0, 3.0, 3.0);  // far outside: every box at 1.4 or more
  double best = 1.0;
  int visited = 0;
  tree.Nearest(p, best, [&](int) { ++visited; });
  EXPECT_EQ(visited, 0);
  best = 0.5 * 0.5;
  const Eigen::Vector3d inside(0.5, 0.5, 0.5);
  tree.Nearest(inside, best, [&](int item) {
    EXPECT_LE(BoxDistance2(boxes.lo[item], boxes.hi[item], inside), 0.25);
    ++visited;
  });
  EXPECT_GT(visited, 0);
  EXPECT_LT(visited, 500);
}

// The same boxes give the same tree: the same items in the same order.
TEST(BoxTree, SameInputSameVisits) {
  std::mt19937 rng(3);
  const Boxes boxes = RandomBoxes(300, rng, false);
  BoxTree a, b;
  a.Build(boxes.lo, boxes.hi);
  b.Build(boxes.lo, boxes.hi);
  b.Build(boxes.lo, boxes.hi);  // (rebuilt: storage reused)
  const Eigen::Vector3d p(0.3, 0.7, 0.2);
  std::vector<int> visits_a, visits_b;
  double best_a = 0.04, best_b = 0.04;
  a.Nearest(p, best_a, [&](int item) { visits_a.push_back(item); });
  b.Nearest(p, best_b, [&](int item) { visits_b.push_back(item); });
  EXPECT_EQ(visits_a, visits_b);
  EXPECT_FALSE(visits_a.empty());
}

}  // namespace
}  // namespace tetcosim
