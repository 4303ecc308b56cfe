#include "collision/broad_phase.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <limits>
#include <random>
#include <tuple>
#include <utility>
#include <vector>

namespace tetcosim {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

// One partner as compared: the partner, and the overlap's corners.
using Found = std::tuple<int, double, double, double, double, double, double>;

Found Make(int a, const Eigen::Vector3d& lo, const Eigen::Vector3d& hi) {
  return {a, lo.x(), lo.y(), lo.z(), hi.x(), hi.y(), hi.z()};
}

bool Empty(const BroadPhaseBox& box) {
  return !(box.lo.array() <= box.hi.array()).all();
}

// Per object, its partners by brute force over every pair: boxes that meet
// (closed), not both rigid, itself with self-collision; left-out (empty)
// boxes have none. Sorted.
std::vector<std::vector<Found>> BruteForcePartners(const std::vector<BroadPhaseBox>& boxes) {
  const int n = static_cast<int>(boxes.size());
  std::vector<std::vector<Found>> partners(n);
  for (int b = 0; b < n; ++b) {
    for (int a = 0; a < n; ++a) {
      if (Empty(boxes[a]) || Empty(boxes[b])) continue;
      if (a == b ? !boxes[a].self_collision : boxes[a].rigid && boxes[b].rigid) continue;
      const Eigen::Vector3d lo = boxes[a].lo.cwiseMax(boxes[b].lo);
      const Eigen::Vector3d hi = boxes[a].hi.cwiseMin(boxes[b].hi);
      if ((lo.array() <= hi.array()).all()) partners[b].push_back(Make(a, lo, hi));
    }
  }
  return partners;
}

// The broad phase's partners, search boxes and partnered objects against
// brute force.
void ExpectMatchesBruteForce(const BroadPhase& broad_phase,
                             const std::vector<BroadPhaseBox>& boxes) {
  const std::vector<std::vector<Found>> expected = BruteForcePartners(boxes);
  std::vector<int> partnered;
  for (int b = 0; b < static_cast<int>(boxes.size()); ++b) {
    std::vector<Found> found;
    Eigen::Vector3d search_lo = Eigen::Vector3d::Constant(kInf);
    Eigen::Vector3d search_hi = Eigen::Vector3d::Constant(-kInf);
    for (int i = broad_phase.partner_begin(b); i < broad_phase.partner_end(b); ++i) {
      const BroadPhase::Partner& partner = broad_phase.partner(i);
      found.push_back(Make(partner.object, partner.lo, partner.hi));
      search_lo = search_lo.cwiseMin(partner.lo);
      search_hi = search_hi.cwiseMax(partner.hi);
    }
    std::sort(found.begin(), found.end());
    ASSERT_EQ(found, expected[b]) << "object " << b;
    EXPECT_EQ(broad_phase.num_partners(b), static_cast<int>(found.size()));
    EXPECT_EQ(broad_phase.search_lo(b), search_lo) << "object " << b;
    EXPECT_EQ(broad_phase.search_hi(b), search_hi) << "object " << b;
    if (!found.empty()) partnered.push_back(b);
  }
  EXPECT_EQ(broad_phase.partnered(), partnered);
}

// n random boxes, spread over a box `extent` long, their corners on a grid
// of `step` (so that many touch or share a low side along every axis, ties
// the sort must break), some rigid, some with self-collision, some left
// out (empty, or NaN).
std::vector<BroadPhaseBox> RandomBoxes(int n, const Eigen::Vector3d& extent, double step,
                                       std::mt19937& rng) {
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::uniform_int_distribution<int> size(0, 3);
  std::vector<BroadPhaseBox> boxes(n);
  for (BroadPhaseBox& box : boxes) {
    for (int k = 0; k < 3; ++k) {
      box.lo[k] = std::floor(unit(rng) * extent[k] / step) * step;
      box.hi[k] = box.lo[k] + size(rng) * step;
    }
    box.rigid = unit(rng) < 0.3;
    box.self_collision = unit(rng) < 0.2;
    const double u = unit(rng);
    if (u < 0.05) {  // as the solver leaves out a non-finite object
      box.lo.setConstant(kInf);
      box.hi.setConstant(-kInf);
    } else if (u < 0.08) {
      std::swap(box.lo.y(), box.hi.y());
      box.hi.y() -= step;  // (empty in y only)
    } else if (u < 0.1) {
      box.lo.z() = std::numeric_limits<double>::quiet_NaN();
    }
  }
  return boxes;
}

// Random scenes of up to 500 boxes, spread along each axis in turn (the
// sweep axis follows the spread), and packed in a cube.
TEST(BroadPhase, MatchesBruteForce) {
  std::mt19937 rng(11);
  BroadPhase broad_phase;  // (reused: its buffers from larger scenes)
  for (int n : {0, 1, 2, 5, 37, 500}) {
    for (const Eigen::Vector3d& extent :
         {Eigen::Vector3d(20.0, 2.0, 2.0), Eigen::Vector3d(2.0, 20.0, 2.0),
          Eigen::Vector3d(2.0, 2.0, 20.0), Eigen::Vector3d(4.0, 4.0, 4.0)}) {
      const std::vector<BroadPhaseBox> boxes = RandomBoxes(n, extent, 0.5, rng);
      broad_phase.Find(boxes);
      SCOPED_TRACE(testing::Message() << n << " boxes over " << extent.transpose());
      ExpectMatchesBruteForce(broad_phase, boxes);
    }
  }
}

// Piles wide along two axes, of 600 to 3000 boxes, are swept in strips (a
// box in each strip it reaches into, a pair taken in one of them): the same
// partners as brute force, with corners on a grid that puts many on the
// strips' sides, boxes of zero extent, one box across the whole pile and one
// far outside it.
TEST(BroadPhase, StripsMatchBruteForce) {
  std::mt19937 rng(7);
  BroadPhase broad_phase;
  for (int n : {600, 3000}) {
    for (const Eigen::Vector3d& extent :
         {Eigen::Vector3d(30.0, 30.0, 1.0), Eigen::Vector3d(1.0, 30.0, 60.0),
          Eigen::Vector3d(40.0, 2.0, 20.0)}) {
      std::vector<BroadPhaseBox> boxes = RandomBoxes(n, extent, 0.5, rng);
      boxes[n / 2].lo = Eigen::Vector3d::Zero();  // across the pile
      boxes[n / 2].hi = extent;
      boxes[n / 3].lo = 1e3 * extent;  // beyond it
      boxes[n / 3].hi = 1e3 * extent + Eigen::Vector3d::Ones();
      broad_phase.Find(boxes);
      SCOPED_TRACE(testing::Message() << n << " boxes over " << extent.transpose());
      EXPECT_GE(broad_phase.num_strips(), 8);  // (else this would test the plain sweep)
      ExpectMatchesBruteForce(broad_phase, boxes);
    }
  }
  // a row along one axis stays one strip
  const std::vector<BroadPhaseBox> row = RandomBoxes(3000, {300.0, 1.0, 1.0}, 0.5, rng);
  broad_phase.Find(row);
  EXPECT_EQ(broad_phase.num_strips(), 1);
  ExpectMatchesBruteForce(broad_phase, row);
}

// Every box the same, all rigid but one: the one deformable is everyone's
// partner, the rigid ones none of each other's; ties everywhere.
TEST(BroadPhase, CoincidentBoxesAndRigidPairs) {
  std::vector<BroadPhaseBox> boxes(9);
  for (BroadPhaseBox& box : boxes) {
    box.lo = Eigen::Vector3d(0.0, 0.0, 0.0);
    box.hi = Eigen::Vector3d(1.0, 1.0, 1.0);
    box.rigid = true;
  }
  boxes[4].rigid = false;
  BroadPhase broad_phase;
  broad_phase.Find(boxes);
  ExpectMatchesBruteForce(broad_phase, boxes);
  EXPECT_EQ(broad_phase.num_partners(4), 8);
  EXPECT_EQ(broad_phase.num_partners(0), 1);
}

// The partners' order depends only on the input: a reused broad phase gives
// the order of a new one.
TEST(BroadPhase, DeterministicOrder) {
  std::mt19937 rng(3);
  const std::vector<BroadPhaseBox> small = RandomBoxes(50, {3.0, 3.0, 3.0}, 0.25, rng);
  const std::vector<BroadPhaseBox> large = RandomBoxes(400, {6.0, 6.0, 6.0}, 0.25, rng);
  // (and in strips: a pile of 2000 after one of 3000)
  const std::vector<BroadPhaseBox> pile = RandomBoxes(2000, {20.0, 20.0, 1.0}, 0.25, rng);
  const std::vector<BroadPhaseBox> wider = RandomBoxes(3000, {40.0, 30.0, 1.0}, 0.25, rng);
  for (const auto& [first, second] :
       {std::pair(&large, &small), std::pair(&wider, &pile), std::pair(&pile, &small)}) {
    BroadPhase reused, fresh;
    reused.Find(*first);
    reused.Find(*second);
    fresh.Find(*second);
    ASSERT_EQ(reused.num_strips(), fresh.num_strips());
    if (second == &pile) {
      EXPECT_GE(fresh.num_strips(), 8);  // (it is cut)
    }
    for (int b = 0; b < static_cast<int>(second->size()); ++b) {
      ASSERT_EQ(reused.partner_begin(b), fresh.partner_begin(b));
      ASSERT_EQ(reused.partner_end(b), fresh.partner_end(b));
      for (int i = fresh.partner_begin(b); i < fresh.partner_end(b); ++i) {
        EXPECT_EQ(reused.partner(i).object, fresh.partner(i).object);
      }
    }
  }
}

}  // namespace
}  // namespace tetcosim
