#pragma once

// Groups (key, value) pairs by key in compressed rows, a counting sort: the
// values of key k are values[offsets[k] .. offsets[k + 1]), in the order the
// pairs come. for_each_pair(emit) must call emit(key, value) for every pair,
// keys in [0, num_keys), the same sequence each time: it runs twice (count,
// then place). No allocation once offsets and values have grown to size.

#include <numeric>
#include <vector>

namespace tetcosim {

template <typename ForEachPair>
void GroupByKey(int num_keys, const ForEachPair& for_each_pair, std::vector<int>& offsets,
                std::vector<int>& values) {
  offsets.assign(num_keys + 1, 0);
  for_each_pair([&](int key, int) { ++offsets[key + 1]; });
  std::partial_sum(offsets.begin(), offsets.end(), offsets.begin());
  values.resize(offsets[num_keys]);
  // place through offsets[k] (which walks to the end of row k, the start of
  // row k + 1), then shift the starts back
  for_each_pair([&](int key, int value) { values[offsets[key]++] = value; });
  for (int k = num_keys; k > 0; --k) offsets[k] = offsets[k - 1];
  offsets[0] = 0;
}

}  // namespace tetcosim
