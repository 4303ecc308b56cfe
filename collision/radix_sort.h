#pragma once

// A stable least-significant-digit radix sort of (key, value) pairs: the
// Morton codes of BoxTree's build and the buckets of SpatialHash's bulk
// build.

#include <algorithm>
#include <utility>
#include <vector>

#include "mesh/parallel_for.h"

namespace tetcosim {

// Sorts the first n pairs (keys[i], values[i]) by key, stably, where every
// key is below 2^key_bits: digits of up to 11 bits, as few passes as
// key_bits needs. On `threads` threads, each counting and placing a
// contiguous part of the pairs. Each pass moves the pairs into the scratch
// vectors and swaps them with keys and values, so the sorted pairs end in
// keys and values (all four hold at least n). counts: a digit count per
// thread (grown here).
template <typename Key>
void RadixSortPairs(int n, int key_bits, int threads, std::vector<Key>& keys,
                    std::vector<int>& values, std::vector<Key>& key_scratch,
                    std::vector<int>& value_scratch, std::vector<int>& counts) {
  const int passes = (std::max(1, key_bits) + 10) / 11;
  const int digit_bits = (std::max(1, key_bits) + passes - 1) / passes;
  const int num_digits = 1 << digit_bits;
  const unsigned mask = num_digits - 1;
  if (static_cast<int>(counts.size()) < threads * num_digits) counts.resize(threads * num_digits);
  auto part_begin = [&](int t) { return static_cast<int>(static_cast<long>(n) * t / threads); };
  for (int pass = 0; pass < passes; ++pass) {
    const int shift = pass * digit_bits;
    auto digit = [&](int i) { return (static_cast<unsigned>(keys[i]) >> shift) & mask; };
    ParallelFor(threads, 0, threads, [&](int t) {
      int* count = counts.data() + t * num_digits;
      std::fill(count, count + num_digits, 0);
      for (int i = part_begin(t); i < part_begin(t + 1); ++i) ++count[digit(i)];
    });
    // where each (digit, thread) starts: digit by digit, thread by thread
    for (int d = 0, sum = 0; d < num_digits; ++d) {
      for (int t = 0; t < threads; ++t) {
        int& count = counts[t * num_digits + d];
        const int c = count;
        count = sum;
        sum += c;
      }
    }
    ParallelFor(threads, 0, threads, [&](int t) {
      int* next = counts.data() + t * num_digits;
      for (int i = part_begin(t); i < part_begin(t + 1); ++i) {
        const int at = next[digit(i)]++;
        key_scratch[at] = keys[i];
        value_scratch[at] = values[i];
      }
    });
    keys.swap(key_scratch);
    values.swap(value_scratch);
  }
}

}  // namespace tetcosim
