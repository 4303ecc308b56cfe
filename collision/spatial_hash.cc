#include "collision/spatial_hash.h"

#include <algorithm>
#include <bit>
#include <cassert>
#include <cmath>
#include <limits>

#include "collision/radix_sort.h"
#include "mesh/parallel_for.h"
#include "mesh/vector_room.h"

namespace tetcosim {

int NextPrime(int n) {
  auto is_prime = [](int m) {
    if (m < 2) return false;
    for (int d = 2; static_cast<long>(d) * d <= m; ++d) {
      if (m % d == 0) return false;
    }
    return true;
  };
  while (!is_prime(n)) ++n;
  return n;
}

void SpatialHash::Reset(double cell_size, int num_items) {
  assert(cell_size > 0.0 && std::isfinite(cell_size));
  cell_size_ = cell_size;
  inverse_cell_size_ = 1.0 / cell_size;
  int wanted = 2 * std::max(num_items, 16) + 1;
  if (static_cast<int>(table_size_) < wanted) {
    // (growing, at least twice the size: a count that creeps up from
    // solve to solve then reallocates a few times, not at each new high)
    const long grown = std::max<long>(wanted, 2 * static_cast<long>(table_size_) + 1);
    table_size_ = static_cast<std::uint64_t>(
        NextPrime(static_cast<int>(std::min<long>(grown, std::numeric_limits<int>::max() / 2))));
    modulo_magic_ = UINT64_MAX / table_size_ + 1;
    slots_.assign(table_size_, Slot{0, 0, 0});
    round_ = 0;
  }
  ++round_;
  if (round_ == 0) {  // wrapped after 2^32 rounds: stamps would be ambiguous
    for (Slot& slot : slots_) slot.stamp = 0;
    round_ = 1;
  }
  used_buckets_.clear();
  inserted_item_.clear();
  inserted_bucket_.clear();
  num_items_ = 0;
}

void SpatialHash::Build() {
  // counting sort: each used bucket's range starts after the previous one's
  int begin = 0;
  for (int bucket : used_buckets_) {
    Slot& slot = slots_[bucket];
    slot.begin = begin;
    begin += slot.count;
    slot.count = 0;  // counts again while the items are placed
  }
  num_items_ = begin;
  if (static_cast<int>(items_.size()) < num_items_) items_.resize(num_items_);
  for (size_t i = 0; i < inserted_item_.size(); ++i) {
    Slot& slot = slots_[inserted_bucket_[i]];
    items_[slot.begin + slot.count++] = inserted_item_[i];
  }
}

void SpatialHash::ResizeInsertions(int n) {
  ResizeWithRoom(inserted_bucket_, n);
  ResizeWithRoom(inserted_item_, n);
}

void SpatialHash::BuildInsertions(int num_threads, int min_sorted) {
  const int n = static_cast<int>(inserted_item_.size());
  if (num_threads > 1 && n >= min_sorted) {
    BuildSorted(std::clamp(n / 4096, 1, num_threads));
    return;
  }
  // Insert's count, then Build
  for (int i = 0; i < n; ++i) Count(inserted_bucket_[i]);
  Build();
}

void SpatialHash::BuildSorted(int threads) {
  const int n = static_cast<int>(inserted_item_.size());
  // each thread takes a contiguous part of the insertions (part t: [n t /
  // T, n (t + 1) / T)), or of the sorted entries
  auto part_begin = [&](int t) { return static_cast<int>(static_cast<long>(n) * t / threads); };
  if (static_cast<int>(sorted_bucket_.size()) < n) {
    sorted_bucket_.resize(n);
    sorted_insertion_[0].resize(n);
    sorted_insertion_[1].resize(n);
    first_run_.resize(n);
    first_count_.resize(n);
  }
  if (static_cast<int>(part_count_.size()) < threads + 1) part_count_.resize(threads + 1);
  // 1. the insertions' numbers sorted by bucket, stably (the insertions'
  // own buckets are not needed after: they are the sort's)
  std::vector<int>& insertions = sorted_insertion_[0];
  ParallelFor(threads, 0, threads, [&](int t) {
    for (int i = part_begin(t); i < part_begin(t + 1); ++i) insertions[i] = i;
  });
  RadixSortPairs(n, static_cast<int>(std::bit_width(table_size_ - 1)), threads, inserted_bucket_,
                 insertions, sorted_bucket_, sorted_insertion_[1], digit_count_);
  const int* bucket = inserted_bucket_.data();
  const int* insertion = insertions.data();
  // 2. the buckets in the order of their first insertion, as Build has
  // them: each bucket's run of sorted entries is listed under its first
  // insertion's number (the run's first entry: the sort is stable)
  ParallelFor(threads, 0, threads, [&](int t) {
    std::fill(first_count_.begin() + part_begin(t), first_count_.begin() + part_begin(t + 1), 0);
  });
  ParallelFor(threads, 0, threads, [&](int t) {
    for (int r = part_begin(t); r < part_begin(t + 1); ++r) {
      if (r > 0 && bucket[r] == bucket[r - 1]) continue;
      int end = r + 1;
      while (end < n && bucket[end] == bucket[r]) ++end;
      first_run_[insertion[r]] = r;
      first_count_[insertion[r]] = end - r;
    }
  });
  // 3. the entries, run after run in that order, and the slots
  ParallelFor(threads, 0, threads, [&](int t) {
    int sum = 0;
    for (int i = part_begin(t); i < part_begin(t + 1); ++i) sum += first_count_[i];
    part_count_[t + 1] = sum;
  });
  part_count_[0] = 0;
  for (int t = 0; t < threads; ++t) part_count_[t + 1] += part_count_[t];
  num_items_ = n;
  if (static_cast<int>(items_.size()) < n) items_.resize(n);
  ParallelFor(threads, 0, threads, [&](int t) {
    int begin = part_count_[t];
    for (int i = part_begin(t); i < part_begin(t + 1); ++i) {
      const int count = first_count_[i];
      if (count == 0) continue;
      const int r = first_run_[i];
      for (int k = 0; k < count; ++k) items_[begin + k] = inserted_item_[insertion[r + k]];
      slots_[bucket[r]] = Slot{round_, begin, count};
      begin += count;
    }
  });
}

}  // namespace tetcosim
