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
  __extension__ typedef unsigned __int128 Uint128;

 public:
  // Starts a new round: cell size (> 0, metres) and the number of items that
  // will be inserted (sizes the table to a prime above 2 * num_items).
  void Reset(double cell_size, int num_items);

  double cell_size() const { return cell_size_; }
  int table_size() const { return static_cast<int>(table_size_); }

  Eigen::Vector3i CellOf(const Eigen::Vector3d& p) const {
    return (p * inverse_cell_size_).array().floor().cast<int>();
  }
  // The bucket of a cell. A non-zero `key` (e.g. an object index + 1) mixes
  // in a fourth large prime, so that items of different keys in the same
  // cell go to different buckets and a query for one key does not walk the
  // others' items; key 0 is Teschner's hash exactly.
  int Bucket(const Eigen::Vector3i& cell, int key = 0) const {
    std::uint32_t h = (static_cast<std::uint32_t>(cell.x()) * 73856093u) ^
                      (static_cast<std::uint32_t>(cell.y()) * 19349663u) ^
                      (static_cast<std::uint32_t>(cell.z()) * 83492791u) ^
                      (static_cast<std::uint32_t>(key) * 50331653u);
    // h mod n without a division (Lemire, Kaser, Kurz 2019: exact for all
    // 32-bit h and n)
    std::uint64_t low = modulo_magic_ * h;
    return static_cast<int>((static_cast<Uint128>(low) * table_size_) >> 64);
  }

  // Adds item to the bucket of (cell, key).
  void Insert(const Eigen::Vector3i& cell, int item, int key = 0);

  // Calls visit(item) for every item in the bucket of (cell, key), most
  // recently inserted first (a deterministic order).
  template <typename Visit>
  void ForEach(const Eigen::Vector3i& cell, Visit&& visit, int key = 0) const {
    const Slot& slot = slots_[Bucket(cell, key)];
    if (slot.stamp != round_) return;
    for (int e = slot.head; e >= 0; e = next_[e]) visit(item_[e]);
  }

 private:
  double cell_size_ = 1.0;
  double inverse_cell_size_ = 1.0;
  std::uint32_t round_ = 0;
  struct Slot {
    std::uint32_t stamp;  // round in which the bucket was last used
    int head;             // its first entry
  };
  std::uint64_t table_size_ = 0;    // n, a prime
  std::uint64_t modulo_magic_ = 0;  // 2^64 / n rounded up
  std::vector<Slot> slots_;         // n
  std::vector<int> next_;           // entries: next entry in the same bucket
  std::vector<int> item_;           // entries: the item
  int num_entries_ = 0;
};

// The smallest prime >= n (n >= 2).
int NextPrime(int n);

}  // namespace tetcosim
