#include "collision/box_tree.h"

#include <bit>
#include <cassert>
#include <limits>

#include "collision/radix_sort.h"

namespace tetcosim {

namespace {

// 10 bits of v spread to every third bit (bit i to bit 3 i)
std::uint32_t SpreadBits(std::uint32_t v) {
  v = (v | v << 16) & 0x030000FFu;
  v = (v | v << 8) & 0x0300F00Fu;
  v = (v | v << 4) & 0x030C30C3u;
  v = (v | v << 2) & 0x09249249u;
  return v;
}

// A coordinate's place on a grid of 1024 steps from 0 (NaN: 0).
std::uint32_t GridStep(double scaled) {
  return static_cast<std::uint32_t>(scaled >= 0.0 ? std::min(scaled, 1023.0) : 0.0);
}

}  // namespace

void BoxTree::Build(std::span<const Eigen::Vector3d> lo, std::span<const Eigen::Vector3d> hi) {
  assert(lo.size() == hi.size());
  const int n = static_cast<int>(lo.size());
  nodes_.clear();
  items_.resize(n);
  item_lo_.resize(n);
  item_hi_.resize(n);
  if (n == 0) return;
  // the centres' bounds, and a grid of cubes over them (the same step on
  // every axis, so that a flat set of items is cut along its wide axes)
  const double inf = std::numeric_limits<double>::infinity();
  Eigen::Vector3d centre_lo = Eigen::Vector3d::Constant(inf);
  Eigen::Vector3d centre_hi = Eigen::Vector3d::Constant(-inf);
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector3d centre = 0.5 * (lo[i] + hi[i]);
    centre_lo = centre_lo.cwiseMin(centre);
    centre_hi = centre_hi.cwiseMax(centre);
  }
  const double extent = (centre_hi - centre_lo).maxCoeff();
  const double scale = extent > 0.0 && extent < inf ? 1023.0 / extent : 0.0;
  codes_.resize(n);
  codes_scratch_.resize(n);
  items_scratch_.resize(n);
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector3d step = (0.5 * (lo[i] + hi[i]) - centre_lo) * scale;
    codes_[i] = SpreadBits(GridStep(step.x())) << 2 | SpreadBits(GridStep(step.y())) << 1 |
                SpreadBits(GridStep(step.z()));
    items_[i] = i;
  }
  // by code, stably (30 bits: 3 passes of 10 bits, on this thread)
  RadixSortPairs(n, 30, 1, codes_, items_, codes_scratch_, items_scratch_, digit_count_);
  BuildNode(0, n);
  // the items' boxes leaf by leaf; then the nodes' boxes, children before
  // parents (a node's children come after it)
  for (int i = 0; i < n; ++i) {
    item_lo_[i] = lo[items_[i]];
    item_hi_[i] = hi[items_[i]];
  }
  for (int node = static_cast<int>(nodes_.size()) - 1; node >= 0; --node) {
    Node& box = nodes_[node];
    if (box.count > 0) {
      box.lo = item_lo_[box.first];
      box.hi = item_hi_[box.first];
      for (int i = box.first + 1; i < box.first + box.count; ++i) {
        box.lo = box.lo.cwiseMin(item_lo_[i]);
        box.hi = box.hi.cwiseMax(item_hi_[i]);
      }
    } else {
      box.lo = nodes_[node + 1].lo.cwiseMin(nodes_[box.first].lo);
      box.hi = nodes_[node + 1].hi.cwiseMax(nodes_[box.first].hi);
    }
  }
}

int BoxTree::BuildNode(int begin, int end) {
  const int node = static_cast<int>(nodes_.size());
  const Eigen::Vector3d unset = Eigen::Vector3d::Zero();  // (the box: set by Build)
  if (end - begin <= kLeafSize) {
    nodes_.push_back({unset, unset, begin, end - begin});
    return node;
  }
  nodes_.push_back({unset, unset, -1, 0});
  // where the highest bit in which the run's codes differ turns from 0 to
  // 1 (the codes are sorted); in the middle if they are all the same
  int middle = begin + (end - begin) / 2;
  if (const std::uint32_t differ = codes_[begin] ^ codes_[end - 1]; differ != 0) {
    const std::uint32_t bit = std::uint32_t{1} << (31 - std::countl_zero(differ));
    middle = static_cast<int>(
        std::partition_point(codes_.begin() + begin, codes_.begin() + end,
                             [bit](std::uint32_t code) { return (code & bit) == 0; }) -
        codes_.begin());
  }
  BuildNode(begin, middle);  // (the next node: the left child)
  const int right = BuildNode(middle, end);
  nodes_[node].first = right;
  return node;
}

}  // namespace tetcosim
