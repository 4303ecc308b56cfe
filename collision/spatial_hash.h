#pragma once

// Optimized spatial hashing (Teschner et al., VMV 2003). The uniform grid of
// cell size l is never stored: cell (i, j, k) goes to bucket
//   h = ((i * 73856093) xor (j * 19349663) xor (k * 83492791)) mod n
// with n a prime above the number of hashed items. Every bucket carries the
// time stamp of its last reset, so starting a new round costs O(1) instead of
// clearing the table. Buckets are shared by the cells hashed to them, so a
// query sees items of other cells too: callers re-check what they find.
//
// Allocation-free once warm: storage only grows, when a round has more items
// than any before.

#include <Eigen/Core>
#include <cstdint>
#include <vector>

namespace tetcosim {

class SpatialHash {
 public:
  // Starts a new round: cell size (> 0, metres) and the number of items that
  // will be inserted (sizes the table to a prime above 2 * num_items).
  void Reset(double cell_size, int num_items);

  double cell_size() const { return cell_size_; }
  int table_size() const { return static_cast<int>(head_.size()); }

  Eigen::Vector3i CellOf(const Eigen::Vector3d& p) const {
    return (p * inverse_cell_size_).array().floor().cast<int>();
  }
  int Bucket(const Eigen::Vector3i& cell) const {
    std::uint32_t h = (static_cast<std::uint32_t>(cell.x()) * 73856093u) ^
                      (static_cast<std::uint32_t>(cell.y()) * 19349663u) ^
                      (static_cast<std::uint32_t>(cell.z()) * 83492791u);
    return static_cast<int>(h % static_cast<std::uint32_t>(head_.size()));
  }

  // Adds item to the bucket of cell.
  void Insert(const Eigen::Vector3i& cell, int item);

  // Calls visit(item) for every item in the bucket of cell, most recently
  // inserted first (a deterministic order).
  template <typename Visit>
  void ForEach(const Eigen::Vector3i& cell, Visit&& visit) const {
    int bucket = Bucket(cell);
    if (stamp_[bucket] != round_) return;
    for (int e = head_[bucket]; e >= 0; e = next_[e]) visit(item_[e]);
  }

 private:
  double cell_size_ = 1.0;
  double inverse_cell_size_ = 1.0;
  std::uint32_t round_ = 0;
  std::vector<int> head_;             // n: first entry of each bucket
  std::vector<std::uint32_t> stamp_;  // n: round in which the bucket was last used
  std::vector<int> next_;             // entries: next entry in the same bucket
  std::vector<int> item_;             // entries: the item
  int num_entries_ = 0;
};

// The smallest prime >= n (n >= 2).
int NextPrime(int n);

}  // namespace tetcosim
