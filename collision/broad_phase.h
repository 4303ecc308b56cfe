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
// before it ends along that axis, four at a time. A large pile is first cut
// into strips along the axis where the centres spread next most, each box
// in every strip it reaches into, and swept strip by strip: a box is then
// tested against the boxes of the strips it is in, about as wide as it is,
// not against a slab across the whole pile (in a pile about as wide as
// long, a number that stays flat as the pile grows, where the slab's grows
// as the square root of the pile's size). Deterministic: partners in the
// order found, which depends only on the boxes and flags.

#include <Eigen/Core>
#include <algorithm>
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
  // How many strips the last Find swept (1: the plain sweep; 0 before the
  // first).
  int num_strips() const { return static_cast<int>(strip_offset_.size()) - 1; }

 private:
  // strips [origin + s / inverse_width, origin + (s + 1) / inverse_width)
  // along the strip axis, s = 0 .. count - 1, the first and last open
  // outward
  struct Strips {
    int count = 1;
    double origin = 0.0;
    double inverse_width = 0.0;
    // the strip of coordinate x: monotone in x (NaN: 0)
    int Of(double x) const {
      return static_cast<int>(
          std::min(static_cast<double>(count - 1), std::max(0.0, (x - origin) * inverse_width)));
    }
  };
  Strips MakeStrips(std::span<const BroadPhaseBox> boxes, int num_in, int axis);

  std::vector<int> sweep_order_;                   // #objects, by lo on the sweep axis
  std::vector<int> strip_offset_;                  // #strips + 1: each strip's entries
  std::vector<int> strip_object_;                  // per entry: its object, strip by strip
  std::vector<double> sweep_lo_[3], sweep_hi_[3];  // per entry: its object's box (padded)
  std::vector<double> extent_, centre_;            // scratch: the boxes' extents and centres across
  std::vector<std::array<int, 2>> pairs_;          // (a, b), each pair once, as found
  std::vector<int> partner_offset_;                // #objects + 1
  std::vector<int> partner_fill_;                  // #objects: next place in its row
  std::vector<Partner> partners_;                  // object after object
  std::vector<Eigen::Vector3d> search_lo_, search_hi_;  // #objects
  std::vector<int> partnered_;
  std::vector<char> left_out_;  // #objects: its box is empty
};

}  // namespace tetcosim
