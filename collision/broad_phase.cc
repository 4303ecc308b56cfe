#include "collision/broad_phase.h"

#include <algorithm>
#include <bit>
#include <limits>
#include <numeric>

#include "collision/simd4.h"
#include "mesh/group_by_key.h"

namespace tetcosim {
namespace {

// A pile is cut into strips only where that makes this many strips or more,
// each of this many boxes at least on average: below it, one strip, the
// plain sweep. (Cutting costs about what it saves at fewer: piles of 240
// and 1200 paper spheres, cut into 3 and 6 strips, took 0.3 to 0.7% more
// instructions a solve than in one; 9600, in about 30, 4.4% fewer.)
constexpr int kMinStrips = 8;
constexpr int kMinBoxesPerStrip = 64;
// The strips span the box centres but for 1/kOutlierShare of them at either
// end (MakeStrips).
constexpr int kOutlierShare = 64;

}  // namespace

// Strips as wide as the boxes' median extent across them (so that a box
// reaches into one or two), over the span of all but the outermost
// 1/kOutlierShare of the box centres at either end (a body far from the
// pile does not stretch the strips; the boxes beyond fall in the first or
// last strip), at most one per kMinBoxesPerStrip boxes; one strip when that
// makes fewer than kMinStrips. num_in boxes are not left out (left_out_).
BroadPhase::Strips BroadPhase::MakeStrips(std::span<const BroadPhaseBox> boxes, int num_in,
                                          int axis) {
  Strips strips;
  if (num_in < kMinStrips * kMinBoxesPerStrip) return strips;
  extent_.clear();
  centre_.clear();
  for (int o = 0; o < static_cast<int>(boxes.size()); ++o) {
    if (left_out_[o]) continue;
    extent_.push_back(boxes[o].hi[axis] - boxes[o].lo[axis]);
    centre_.push_back(0.5 * (boxes[o].lo[axis] + boxes[o].hi[axis]));
  }
  std::nth_element(extent_.begin(), extent_.begin() + num_in / 2, extent_.end());
  const int first = num_in / kOutlierShare;
  const int last = num_in - 1 - first;
  std::nth_element(centre_.begin(), centre_.begin() + first, centre_.end());
  std::nth_element(centre_.begin() + first + 1, centre_.begin() + last, centre_.end());
  const double lo = centre_[first];
  const double hi = centre_[last];
  const double count =
      std::min((hi - lo) / extent_[num_in / 2], static_cast<double>(num_in) / kMinBoxesPerStrip);
  if (!(count >= kMinStrips)) return strips;  // (also a median extent of 0 over no span: NaN)
  strips.count = static_cast<int>(count);
  strips.origin = lo;
  strips.inverse_width = strips.count / (hi - lo);
  return strips;
}

void BroadPhase::Find(std::span<const BroadPhaseBox> boxes) {
  const int num_objects = static_cast<int>(boxes.size());
  // (an empty box, or one with NaN, is left out: it sorts last, and its low
  // sides in the sweep are +inf, which meet no finite box)
  left_out_.resize(num_objects);
  for (int o = 0; o < num_objects; ++o) {
    left_out_[o] = !(boxes[o].lo.array() <= boxes[o].hi.array()).all();
  }
  auto left_out = [&](int o) { return left_out_[o] != 0; };
  const double inf = std::numeric_limits<double>::infinity();
  // the sweep axis: the one along which the boxes' centres spread most
  // (their variance), so that the fewest boxes start before a box ends
  // along it (a pile of 9600 spheres, 20 x 80 x 6, swept along x: 360
  // boxes tested a box, 13 overlapping it, and the broad phase was 18% of
  // the solve's instructions; along y, 10%)
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  int num_in = 0;
  for (int o = 0; o < num_objects; ++o) {
    if (left_out(o)) continue;
    mean += 0.5 * (boxes[o].lo + boxes[o].hi);
    ++num_in;
  }
  mean /= std::max(1, num_in);
  Eigen::Vector3d spread = Eigen::Vector3d::Zero();
  for (int o = 0; o < num_objects; ++o) {
    if (left_out(o)) continue;
    spread += (0.5 * (boxes[o].lo + boxes[o].hi) - mean).cwiseAbs2();
  }
  int axis = 0;
  spread.maxCoeff(&axis);  // (the first of equal ones)
  // across the sweep, strips along the axis where the centres spread next
  // most (MakeStrips)
  int strip_axis = axis == 0 ? 1 : 0;
  for (int k = 0; k < 3; ++k) {
    if (k != axis && spread[k] > spread[strip_axis]) strip_axis = k;
  }
  pairs_.clear();
  sweep_order_.resize(num_objects);
  for (int o = 0; o < num_objects; ++o) sweep_order_[o] = o;
  std::sort(sweep_order_.begin(), sweep_order_.end(), [&](int a, int b) {
    const double a_lo = left_out(a) ? inf : boxes[a].lo[axis];
    const double b_lo = left_out(b) ? inf : boxes[b].lo[axis];
    return a_lo != b_lo ? a_lo < b_lo : a < b;
  });
  const Strips strips = MakeStrips(boxes, num_in, strip_axis);
  // each strip's boxes in sweep order (a box in every strip it reaches
  // into), by coordinate
  const bool cut = strips.count > 1;  // (one strip, the common case of a few bodies)
  GroupByKey(
      strips.count,
      [&](auto&& emit) {
        for (int o : sweep_order_) {
          if (left_out(o)) continue;
          if (!cut) {
            emit(0, o);
            continue;
          }
          const int last = strips.Of(boxes[o].hi[strip_axis]);
          for (int s = strips.Of(boxes[o].lo[strip_axis]); s <= last; ++s) emit(s, o);
        }
      },
      strip_offset_, strip_object_);
  const int num_entries = static_cast<int>(strip_object_.size());
  for (int k = 0; k < 3; ++k) {
    ResizePadded(sweep_lo_[k], num_entries);
    ResizePadded(sweep_hi_[k], num_entries);
    for (int n = 0; n < num_entries; ++n) {
      sweep_lo_[k][n] = boxes[strip_object_[n]].lo[k];
      sweep_hi_[k][n] = boxes[strip_object_[n]].hi[k];
    }
  }
  // each pair once, in the order found (a self pair as (a, a)), and each
  // object's number of partners: a box is tested against the boxes after
  // it in its strip that start before it ends along the sweep axis, four at
  // a time (in a pile of 120 spheres, one strip, about 50 of them a box); a
  // pair in several strips is taken in the one that holds the low side of
  // its overlap across them (both boxes are in that strip)
  const std::vector<double>& sweep_lo = sweep_lo_[axis];
  partner_offset_.assign(num_objects + 1, 0);
  for (int s = 0; s < strips.count; ++s) {
    const int strip_end = strip_offset_[s + 1];
    for (int n = strip_offset_[s]; n < strip_end; ++n) {
      const int a = strip_object_[n];
      const double a_lo = boxes[a].lo[strip_axis];
      if ((!cut || strips.Of(a_lo) == s) && MayCollide(boxes[a], boxes[a], /*same=*/true)) {
        pairs_.push_back({a, a});
        ++partner_offset_[a + 1];
      }
      // (the boxes that start before this one ends, by bisection)
      const int end =
          static_cast<int>(std::upper_bound(sweep_lo.begin() + n + 1, sweep_lo.begin() + strip_end,
                                            boxes[a].hi[axis]) -
                           sweep_lo.begin());
      const Box4 box(boxes[a].lo, boxes[a].hi);
      for (int j = n + 1; j < end; j += 4) {
        for (unsigned bits = box.Overlapping(sweep_lo_, sweep_hi_, j, end); bits != 0;
             bits &= bits - 1) {
          const int b = strip_object_[j + std::countr_zero(bits)];
          if (cut && strips.Of(std::max(a_lo, boxes[b].lo[strip_axis])) != s) continue;
          if (!MayCollide(boxes[a], boxes[b], /*same=*/false)) continue;
          pairs_.push_back({a, b});
          ++partner_offset_[a + 1];
          ++partner_offset_[b + 1];
        }
      }
    }
  }
  // per object its partners, in the order their pairs were found (a
  // counting sort: one pass over the pairs, which puts each in both of its
  // objects' rows), with the overlap of the two boxes. (Not GroupByKey,
  // whose entries would have to name the pair and its side, read back
  // through an index: 120 spheres, 4,811,361 instructions a solve against
  // 4,754,333.)
  std::partial_sum(partner_offset_.begin(), partner_offset_.end(), partner_offset_.begin());
  partnered_.clear();
  for (int o = 0; o < num_objects; ++o) {
    if (partner_offset_[o + 1] > partner_offset_[o]) partnered_.push_back(o);
  }
  partners_.resize(partner_offset_[num_objects]);
  partner_fill_.assign(partner_offset_.begin(), partner_offset_.end() - 1);
  search_lo_.assign(num_objects, Eigen::Vector3d::Constant(inf));
  search_hi_.assign(num_objects, Eigen::Vector3d::Constant(-inf));
  auto add_partner = [&](int b, int a) {  // a as b's partner
    Partner& partner = partners_[partner_fill_[b]++];
    partner.object = a;
    partner.lo = boxes[a].lo.cwiseMax(boxes[b].lo);
    partner.hi = boxes[a].hi.cwiseMin(boxes[b].hi);
    search_lo_[b] = search_lo_[b].cwiseMin(partner.lo);
    search_hi_[b] = search_hi_[b].cwiseMax(partner.hi);
  };
  for (const auto& [a, b] : pairs_) {
    add_partner(a, b);
    if (b != a) add_partner(b, a);
  }
}

}  // namespace tetcosim
