#include "collision/spatial_hash.h"

#include <algorithm>
#include <cassert>
#include <cmath>

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
    table_size_ = static_cast<std::uint64_t>(NextPrime(wanted));
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

void SpatialHash::Insert(const Eigen::Vector3i& cell, int item, int key) {
  const int bucket = Bucket(cell, key);
  Slot& slot = slots_[bucket];
  if (slot.stamp != round_) {
    slot.stamp = round_;
    slot.count = 0;
    used_buckets_.push_back(bucket);
  }
  ++slot.count;
  inserted_item_.push_back(item);
  inserted_bucket_.push_back(bucket);
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

}  // namespace tetcosim
