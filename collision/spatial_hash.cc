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
  if (static_cast<int>(head_.size()) < wanted) {
    int n = NextPrime(wanted);
    head_.assign(n, -1);
    stamp_.assign(n, 0);
    round_ = 0;
  }
  ++round_;
  if (round_ == 0) {  // wrapped after 2^32 rounds: stamps would be ambiguous
    std::fill(stamp_.begin(), stamp_.end(), 0u);
    round_ = 1;
  }
  num_entries_ = 0;
}

void SpatialHash::Insert(const Eigen::Vector3i& cell, int item) {
  int bucket = Bucket(cell);
  if (stamp_[bucket] != round_) {
    stamp_[bucket] = round_;
    head_[bucket] = -1;
  }
  if (num_entries_ == static_cast<int>(item_.size())) {
    item_.push_back(item);
    next_.push_back(head_[bucket]);
  } else {
    item_[num_entries_] = item;
    next_[num_entries_] = head_[bucket];
  }
  head_[bucket] = num_entries_++;
}

}  // namespace tetcosim
