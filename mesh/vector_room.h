#pragma once

// std::vector sized with room to grow, for arrays reused from step to step:
// a count that creeps up (contacts, constraints) then reallocates a few
// times, not at each new high, as std::vector's assign does (it allocates
// exactly what it is given once past the capacity).

#include <algorithm>
#include <cstddef>
#include <vector>

namespace tetcosim {

// v.reserve(n), twice the capacity (at least n) once n passes it
template <typename T>
void ReserveWithRoom(std::vector<T>& v, std::size_t n) {
  if (n > v.capacity()) v.reserve(std::max(n, 2 * v.capacity()));
}

// v.assign(n, value) with ReserveWithRoom
template <typename T>
void AssignWithRoom(std::vector<T>& v, std::size_t n, const T& value) {
  ReserveWithRoom(v, n);
  v.assign(n, value);
}

// v.resize(n) with ReserveWithRoom
template <typename T>
void ResizeWithRoom(std::vector<T>& v, std::size_t n) {
  ReserveWithRoom(v, n);
  v.resize(n);
}

}  // namespace tetcosim
