#pragma once

// A bounding-volume hierarchy over axis-aligned boxes, for nearest-item
// queries (the closest-feature search over a body's surface triangles) and
// overlap queries (stage 2's segments against triangles too large to hash).
//
// Build sorts the items along a Z-order (Morton) curve through their box
// centres (10 bits per axis, on a grid of cubes over the centres' bounds)
// with a radix sort, and splits each run of sorted items where the highest
// bit in which the run's codes differ turns from 0 to 1 (an octree cell of
// the grid cut in half along one axis), down to leaves of at most
// kLeafSize items; a run of equal codes is split in half. A binary tree,
// nodes in depth-first order, at most 30 + log2(n) levels deep. (Splitting
// at the median centre along the longest axis instead, with
// std::nth_element, made trees that answered nearest-item queries about as
// fast, but took 7 to 10 times as long to build: 110 to 190 ns per item
// against 15 to 19 on the surfaces of the benchmark's bodies.)
//
// A query visits the nearer child first and passes over every node whose
// box is farther from the point than the best distance so far, so it reads
// about log(n) nodes where a grid search reads every cell within that
// distance (for a point deep inside a finely meshed body: thousands).
//
// Deterministic (the sort is stable: items with the same code stay in
// item order) and allocation-free once warm: storage only grows.

#include <Eigen/Core>
#include <algorithm>
#include <cstdint>
#include <span>
#include <vector>

#include "collision/geometry.h"

namespace tetcosim {

class BoxTree {
 public:
  static constexpr int kLeafSize = 4;

  // Builds the tree over items 0 .. n - 1 with boxes [lo[i], hi[i]].
  void Build(std::span<const Eigen::Vector3d> lo, std::span<const Eigen::Vector3d> hi);

  int num_items() const { return static_cast<int>(items_.size()); }

  // Calls visit(item) for every item whose box meets [lo, hi] (closed
  // boxes: touching counts), in the tree's order (deterministic).
  template <typename Visit>
  void Overlapping(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, Visit&& visit) const {
    if (nodes_.empty()) return;
    int stack[kMaxDepth];
    int top = 0;
    stack[top++] = 0;
    while (top > 0) {
      const int node = stack[--top];
      const Node& n = nodes_[node];
      if (!BoxesOverlap(n.lo, n.hi, lo, hi)) continue;
      if (n.count > 0) {
        for (int i = n.first; i < n.first + n.count; ++i) {
          if (BoxesOverlap(item_lo_[i], item_hi_[i], lo, hi)) visit(items_[i]);
        }
      } else {
        stack[top++] = n.first;   // the right child
        stack[top++] = node + 1;  // the left one, first
      }
    }
  }

  // Calls visit(item) for the items that may lie within sqrt(best) of p,
  // nearer subtrees first; visit may lower best (a squared distance), which
  // prunes what is left. Items whose box is farther than best are never
  // visited.
  template <typename Visit>
  void Nearest(const Eigen::Vector3d& p, double& best, Visit&& visit) const {
    if (nodes_.empty()) return;
    // (depth-first: the stack holds at most one node per level)
    int stack[kMaxDepth];
    double stack_distance[kMaxDepth];
    int top = 0;
    int node = 0;
    double distance = Distance2(nodes_[0], p);
    for (;;) {
      if (distance <= best) {
        const Node& n = nodes_[node];
        if (n.count > 0) {
          for (int i = n.first; i < n.first + n.count; ++i) {
            if (BoxDistance2(item_lo_[i], item_hi_[i], p) <= best) visit(items_[i]);
          }
        } else {
          const int left = node + 1;
          const int right = n.first;
          const double d_left = Distance2(nodes_[left], p);
          const double d_right = Distance2(nodes_[right], p);
          const bool left_first = d_left <= d_right;
          stack[top] = left_first ? right : left;
          stack_distance[top++] = left_first ? d_right : d_left;
          node = left_first ? left : right;
          distance = left_first ? d_left : d_right;
          continue;
        }
      }
      if (top == 0) return;
      node = stack[--top];
      distance = stack_distance[top];
    }
  }

 private:
  // (30 levels of bit splits, then halving runs of equal codes: 62 at most)
  static constexpr int kMaxDepth = 64;
  struct Node {
    Eigen::Vector3d lo, hi;
    int first;  // leaf: its first entry in items_; inner: its right child
    int count;  // leaf: its number of items; inner: 0 (left child: the next node)
  };
  // (always inlined, as BoxDistance2: in the solver's files, large enough,
  // g++ would call it)
  [[gnu::always_inline]] static double Distance2(const Node& node, const Eigen::Vector3d& p) {
    return BoxDistance2(node.lo, node.hi, p);
  }
  // builds the subtree over the sorted items [begin, end) and returns its
  // node (its box is set by Build, from its children's)
  int BuildNode(int begin, int end);

  std::vector<Node> nodes_;
  std::vector<std::uint32_t> codes_, codes_scratch_;  // (during Build) Morton codes, sorted
  std::vector<int> items_scratch_;                    // (during Build)
  std::vector<int> digit_count_;                      // (during Build: the sort's)
  std::vector<int> items_;                            // the items, leaf by leaf
  std::vector<Eigen::Vector3d> item_lo_, item_hi_;    // their boxes, in items_' order
};

}  // namespace tetcosim
