#include "collision/box_tree.h"

#include <cassert>
#include <limits>

namespace tetcosim {

void BoxTree::Build(std::span<const Eigen::Vector3d> lo, std::span<const Eigen::Vector3d> hi) {
  assert(lo.size() == hi.size());
  const int n = static_cast<int>(lo.size());
  nodes_.clear();
  order_.resize(n);
  for (int i = 0; i < n; ++i) order_[i] = {0.5 * (lo[i] + hi[i]), i};
  items_.resize(n);
  item_lo_.resize(n);
  item_hi_.resize(n);
  if (n == 0) return;
  BuildNode(0, n);
  // the items leaf by leaf, with their boxes; then the nodes' boxes,
  // children before parents (a node's children come after it)
  for (int i = 0; i < n; ++i) {
    items_[i] = order_[i].item;
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
  const double inf = std::numeric_limits<double>::infinity();
  Eigen::Vector3d centre_lo = Eigen::Vector3d::Constant(inf);
  Eigen::Vector3d centre_hi = Eigen::Vector3d::Constant(-inf);
  for (int i = begin; i < end; ++i) {
    centre_lo = centre_lo.cwiseMin(order_[i].centre);
    centre_hi = centre_hi.cwiseMax(order_[i].centre);
  }
  int axis = 0;
  (centre_hi - centre_lo).maxCoeff(&axis);
  const int middle = begin + (end - begin) / 2;
  // (ties in the centres broken by item number: the same tree whatever
  // the order nth_element leaves them in)
  std::nth_element(order_.begin() + begin, order_.begin() + middle, order_.begin() + end,
                   [axis](const Centre& a, const Centre& b) {
                     const double ca = a.centre[axis], cb = b.centre[axis];
                     return ca < cb || (ca == cb && a.item < b.item);
                   });
  BuildNode(begin, middle);  // (the next node: the left child)
  const int right = BuildNode(middle, end);
  nodes_[node].first = right;
  return node;
}

}  // namespace tetcosim
