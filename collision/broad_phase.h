#pragma once

// The penetration solver's broad phase: for every object B, its partners,
// the objects A whose boxes overlap B's and that may collide with it (B
// itself with self-collision; never two rigid objects, which the rigid
// engine handles), each with the overlap of the two boxes (where A's
// vertices inside B can lie), and B's search box, the union of those
// overlaps (where anything of B can meet a partner).
//
// Sweep and prune: the boxes sorted by their low side along the axis where
// their centres spread most, each tested against those after it that start
// before it ends along that axis, four at a time. Deterministic: partners in
// the order found, which depends only on the boxes and flags.

#include <Eigen/Core>
#include <array>
#include <span>
#include <vector>

namespace tetcosim {

// Whether object a may collide with object b (`same`: they are one), the
// pair rule of the broad phase and of stage 1 alike: an object with itself
// only with self-collision, two rigid objects never (the rigid engine's
// pair). Object: anything with flags `rigid` and `self_collision`
// (BroadPhaseBox, CollisionObject).
template <typename Object>
constexpr bool MayCollide(const Object& a, const Object& b, bool same) {
  return same ? b.self_collision : !(a.rigid && b.rigid);
}

// An object as the broad phase sees it.
struct BroadPhaseBox {
  // its bounding box (world frame, metres), finite; empty (lo > hi in a
  // coordinate) to leave the object out: it then meets no other
  Eigen::Vector3d lo, hi;
  bool rigid = false;           // rigid objects are not each other's partners
  bool self_collision = false;  // the object is its own partner
};

class BroadPhase {
 public:
  struct Partner {
    Eigen::Vector3d lo, hi;  // the overlap of the two objects' boxes
    int object;              // A
  };

  // Finds every object's partners: A != B is a partner of B when their
  // boxes overlap (closed: touching counts) and they are not both rigid; B
  // is its own with self-collision (unless left out).
  void Find(std::span<const BroadPhaseBox> boxes);

  // Object b's partners are partner(i) for i in [partner_begin(b),
  // partner_end(b)); the numbering runs object after object.
  int partner_begin(int b) const { return partner_offset_[b]; }
  int partner_end(int b) const { return partner_offset_[b + 1]; }
  int num_partners(int b) const { return partner_end(b) - partner_begin(b); }
  const Partner& partner(int i) const { return partners_[i]; }
  // Object b's search box: the union of its partners' overlaps; empty
  // (lo = +inf, hi = -inf) if it has none.
  const Eigen::Vector3d& search_lo(int b) const { return search_lo_[b]; }
  const Eigen::Vector3d& search_hi(int b) const { return search_hi_[b]; }
  // The objects with at least one partner, ascending.
  const std::vector<int>& partnered() const { return partnered_; }

 private:
  std::vector<int> sweep_order_;                        // #objects, by lo on the sweep axis
  std::vector<double> sweep_lo_[3], sweep_hi_[3];       // their boxes in that order (padded)
  std::vector<std::array<int, 2>> pairs_;               // (a, b), each pair once, as found
  std::vector<int> partner_offset_;                     // #objects + 1
  std::vector<int> partner_fill_;                       // #objects: next place in its row
  std::vector<Partner> partners_;                       // object after object
  std::vector<Eigen::Vector3d> search_lo_, search_hi_;  // #objects
  std::vector<int> partnered_;
  std::vector<char> left_out_;  // #objects: its box is empty
};

}  // namespace tetcosim
