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
    slots_.assign(table_size_, Slot{0, -1});
    round_ = 0;
  }
  ++round_;
  if (round_ == 0) {  // wrapped after 2^32 rounds: stamps would be ambiguous
    for (Slot& slot : slots_) slot.stamp = 0;
    round_ = 1;
  }
  num_entries_ = 0;
}

void SpatialHash::Insert(const Eigen::Vector3i& cell, int item, int key) {
  Slot& slot = slots_[Bucket(cell, key)];
  if (slot.stamp != round_) {
    slot.stamp = round_;
    slot.head = -1;
  }
  if (num_entries_ == static_cast<int>(item_.size())) {
    item_.push_back(item);
    next_.push_back(slot.head);
  } else {
    item_[num_entries_] = item;
    next_[num_entries_] = slot.head;
  }
  slot.head = num_entries_++;
}

}  // namespace tetcosim
