#pragma once

// std::vector sized with room to grow, for arrays reused from step to step:
// a count that creeps up (contacts, constraints) then reallocates a few
// times, not at each new high, as std::vector's assign does (it allocates
// exactly what it is given once past the capacity).

#include <Eigen/Core>
#include <algorithm>
#include <cstddef>
#include <new>
#include <vector>

namespace tetcosim {

// v.reserve(n), twice the capacity (at least n) once n passes it
template <typename T, typename Allocator>
void ReserveWithRoom(std::vector<T, Allocator>& v, std::size_t n) {
  if (n > v.capacity()) v.reserve(std::max(n, 2 * v.capacity()));
}

// v.assign(n, value) with ReserveWithRoom
template <typename T, typename Allocator>
void AssignWithRoom(std::vector<T, Allocator>& v, std::size_t n, const T& value) {
  ReserveWithRoom(v, n);
  v.assign(n, value);
}

// v.resize(n) with ReserveWithRoom
template <typename T, typename Allocator>
void ResizeWithRoom(std::vector<T, Allocator>& v, std::size_t n) {
  ReserveWithRoom(v, n);
  v.resize(n);
}

// An Eigen vector of doubles that keeps its storage when its size falls
// and grows it with room (ReserveWithRoom), for a step's arrays whose size
// goes up and down from step to step (the coupled step's, sized by the
// degrees of freedom, which change as rigid trees join and leave): such an
// array reallocates only at a new high. It is an Eigen::Map over storage it
// owns, aligned as Eigen::VectorXd's is (Eigen then loads it aligned), and
// computes as a VectorXd does, to the bit (tests/mesh/vector_room_test.cc).
// Unlike VectorXd, it does not resize on assignment from an expression:
// give it its size first (resize, setZero(n)). Copying one assigns its
// values and size; it cannot be moved (the map points into its own
// storage).
class VectorXdWithRoom : public Eigen::Map<Eigen::VectorXd, Eigen::AlignedMax> {
 public:
  using Base = Eigen::Map<Eigen::VectorXd, Eigen::AlignedMax>;

  VectorXdWithRoom() : Base(nullptr, 0) {}
  VectorXdWithRoom(const VectorXdWithRoom& other) : Base(nullptr, 0) { *this = other; }
  VectorXdWithRoom& operator=(const VectorXdWithRoom& other) {
    if (this != &other) {
      resize(other.size());
      Base::operator=(other);
    }
    return *this;
  }
  using Base::operator=;  // (from an expression of this size)

  // size n: the first min(n, size()) values kept, the rest unset
  void resize(Eigen::Index n) {
    if (n == size()) return;
    ReserveWithRoom(storage_, static_cast<std::size_t>(n));
    if (storage_.size() < storage_.capacity()) storage_.resize(storage_.capacity());
    // (a Map is placed anew to point elsewhere: Eigen's way of re-seating one)
    new (static_cast<Base*>(this)) Base(storage_.data(), n);
  }
  void setZero(Eigen::Index n) {
    resize(n);
    Base::setZero();
  }
  using Base::setZero;

 private:
  std::vector<double, Eigen::aligned_allocator<double>> storage_;
};

}  // namespace tetcosim
