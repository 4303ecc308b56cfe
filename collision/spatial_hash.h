#pragma once

// Optimized spatial hashing (Teschner et al., VMV 2003). The uniform grid of
// cell size l is never stored: cell (i, j, k) goes to bucket
//   h = ((i * 73856093) xor (j * 19349663) xor (k * 83492791)) mod n
// with n a prime above the number of hashed items. Every bucket carries the
// time stamp of its last reset, so starting a new round costs O(1) instead of
// clearing the table. Buckets are shared by the cells hashed to them, so a
// query sees items of other cells too: callers re-check what they find.
//
// A round: Reset, Insert every item, Build, then queries. Build sorts the
// items by bucket (a counting sort over the buckets used in the round), so a
// bucket's items are one contiguous range of entries: a query reads them in
// a row instead of chasing a linked list, and callers may keep per-entry data
// (positions, boxes) in the same order. Insert after Build starts the
// bucket order over: call Build again before the next query.
//
// Allocation-free once warm: storage only grows, when a round has more items
// than any before.

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <span>
#include <vector>

namespace tetcosim {

// Cell coordinates are clamped to [-kMaxGridCell, kMaxGridCell] (2^30 cells:
// a thousand kilometres at millimetre cells), so that any point, however far
// (a body flying off in a diverging simulation), has a cell without
// overflowing int; points beyond share the boundary cells. Clamping keeps
// the order of coordinates, so boxes that meet still share a cell, and
// every caller re-checks what it finds in a bucket: results stay exact,
// only the boundary cells are no longer small. (NaN goes to the upper
// bound.)
inline constexpr double kMaxGridCell = 1 << 30;

inline int GridCoordinate(double scaled) {
  return static_cast<int>(std::max(-kMaxGridCell, std::min(kMaxGridCell, std::floor(scaled))));
}

// The cell (i, j, k) of point p in the uniform grid of cell size
// 1 / inverse_cell_size.
inline Eigen::Vector3i GridCell(const Eigen::Vector3d& p, double inverse_cell_size) {
  return {GridCoordinate(p.x() * inverse_cell_size), GridCoordinate(p.y() * inverse_cell_size),
          GridCoordinate(p.z() * inverse_cell_size)};
}

class SpatialHash {
  __extension__ typedef unsigned __int128 Uint128;

 public:
  // Starts a new round: cell size (> 0, metres) and the number of items that
  // will be inserted (sizes the table to a prime above 2 * num_items).
  void Reset(double cell_size, int num_items);

  double cell_size() const { return cell_size_; }
  int table_size() const { return static_cast<int>(table_size_); }

  Eigen::Vector3i CellOf(const Eigen::Vector3d& p) const { return GridCell(p, inverse_cell_size_); }
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

  // Adds item to the bucket of (cell, key). (Inline: stage 2's triangle
  // hashes make one insertion per cell of each triangle's box.)
  void Insert(const Eigen::Vector3i& cell, int item, int key = 0) {
    const int bucket = Bucket(cell, key);
    Count(bucket);
    inserted_item_.push_back(item);
    inserted_bucket_.push_back(bucket);
  }

  // Sorts the items inserted so far by bucket; queries need it.
  void Build();

  // A round's insertions all at once, made on several threads (instead of
  // Insert, then Build): after Reset, ResizeInsertions(n), then
  // SetInsertion(i, ...) for every i in [0, n) (from any thread, each i
  // once), then BuildInsertions: the same entries in the same order as
  // Insert in the order of i and Build. From min_sorted insertions on more
  // than one thread, it sorts them by bucket on every thread instead (a
  // stable radix sort, then the buckets put in the order of their first
  // insertion, as Build has them; Build counts per slot, reading and
  // writing an insertion's slot at random, twice, on one thread). Below,
  // the sort's fixed passes cost more than the threads save (100k tets,
  // 4k insertions: 96 -> 143 us).
  static constexpr int kMinSortedInsertions = 16384;
  void ResizeInsertions(int n);
  void SetInsertion(int i, const Eigen::Vector3i& cell, int item, int key = 0) {
    inserted_bucket_[i] = Bucket(cell, key);
    inserted_item_[i] = item;
  }
  void BuildInsertions(int num_threads, int min_sorted = kMinSortedInsertions);

  // The entries of the bucket of (cell, key): a range [begin, end) of
  // indices into items(), in insertion order (deterministic). Empty if no
  // item went to that bucket in this round.
  struct Range {
    int begin = 0;
    int end = 0;
  };
  Range Find(const Eigen::Vector3i& cell, int key = 0) const {
    const Slot& slot = slots_[Bucket(cell, key)];
    if (slot.stamp != round_) return {};
    return {slot.begin, slot.begin + slot.count};
  }

  // Every item of the round, grouped by bucket (after Build).
  std::span<const int> items() const { return {items_.data(), static_cast<size_t>(num_items_)}; }
  int num_items() const { return num_items_; }

  // Calls visit(range) with the bucket of (cell, key) of every cell from lo
  // to hi (inclusive, z outermost, then y, then x).
  // (Always inlined, as stage 1's lambdas that call it: the caller's loop
  // over a chunk's cells is the solver's innermost; left to g++, which
  // inlines by how large a file's functions grow, it was called out of line
  // in some builds, 3% more instructions in stage 1.)
  template <typename Visit>
  [[gnu::always_inline]] void ForEachBucket(const Eigen::Vector3i& lo, const Eigen::Vector3i& hi,
                                            int key, Visit&& visit) const {
    for (int k = lo.z(); k <= hi.z(); ++k) {
      for (int j = lo.y(); j <= hi.y(); ++j) {
        for (int i = lo.x(); i <= hi.x(); ++i) visit(Find({i, j, k}, key));
      }
    }
  }

  // Calls visit(item) for every item in the bucket of (cell, key).
  template <typename Visit>
  void ForEach(const Eigen::Vector3i& cell, Visit&& visit, int key = 0) const {
    Range range = Find(cell, key);
    for (int e = range.begin; e < range.end; ++e) visit(items_[e]);
  }

 private:
  double cell_size_ = 1.0;
  double inverse_cell_size_ = 1.0;
  std::uint32_t round_ = 0;
  struct Slot {
    std::uint32_t stamp;  // round in which the bucket was last used
    int begin;            // its first entry in items_ (after Build)
    int count;            // its number of entries
  };
  std::uint64_t table_size_ = 0;      // n, a prime
  std::uint64_t modulo_magic_ = 0;    // 2^64 / n rounded up
  std::vector<Slot> slots_;           // n
  std::vector<int> used_buckets_;     // buckets used in this round, in first-use order
  std::vector<int> inserted_item_;    // per insertion: the item
  std::vector<int> inserted_bucket_;  // per insertion: its bucket
  std::vector<int> items_;            // the items, grouped by bucket (after Build)
  // One more insertion into bucket: its count in this round (a bucket's
  // first use in the round resets it and lists the bucket).
  void Count(int bucket) {
    Slot& slot = slots_[bucket];
    if (slot.stamp != round_) {
      slot.stamp = round_;
      slot.count = 0;
      used_buckets_.push_back(bucket);
    }
    ++slot.count;
  }
  // the sorted build (BuildInsertions on several threads)
  void BuildSorted(int threads);
  // BuildSorted's buffers: the radix sort's other buffer for the buckets,
  // the insertions' numbers and its other buffer for them, a digit count
  // per thread; per insertion, if it is its bucket's first, the bucket's
  // run of sorted entries (start, size; 0 if not); per thread, the entries
  // before its part
  std::vector<int> sorted_bucket_, sorted_insertion_[2];
  std::vector<int> digit_count_;
  std::vector<int> first_run_, first_count_;
  std::vector<int> part_count_;
  int num_items_ = 0;
};

// The smallest prime >= n (n >= 2).
int NextPrime(int n);

}  // namespace tetcosim
