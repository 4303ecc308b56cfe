#pragma once

// What the penetration solver takes of an object: its shared topology, its
// current positions, and what the caller knows of them (a fixed body, a
// rigid motion, their box).

#include <Eigen/Core>
#include <bit>
#include <cstdint>
#include <limits>
#include <optional>

#include "mesh/tet_mesh.h"

namespace tetcosim {

// The box of a set of positions and whether they are all finite, grown one
// position at a time: the solver's own pass over an object's positions, and
// what a caller that writes the positions anyway (the bridge placing a
// moving body's proxy) can accumulate as it writes them (RigidFrame::bounds).
struct PositionBounds {
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  Eigen::Vector3d hi = Eigen::Vector3d::Constant(-std::numeric_limits<double>::infinity());
  // the bits of p - p, or-ed: +0 (no bit set) while every coordinate is
  // finite, a NaN's once one is infinite or NaN (summing p - p instead, a
  // chain of adds, made the solver's hash stage slower: 5.8 against 5.0 us
  // on the 70% cubes)
  std::uint64_t non_finite = 0;

  void Add(const Eigen::Vector3d& p) {
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
    non_finite |= std::bit_cast<std::uint64_t>(p.x() - p.x()) |
                  std::bit_cast<std::uint64_t>(p.y() - p.y()) |
                  std::bit_cast<std::uint64_t>(p.z() - p.z());
  }
  bool finite() const { return non_finite == 0; }

  // Add of every position of x, in order.
  static PositionBounds Of(const Positions& x);
};

// A rigid motion: a point's world position is rotation * p + translation
// for its position p in the body frame.
struct RigidFrame {
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();
  // Optional: the box of the object's positions, PositionBounds::Add of
  // every one of them as given, so that the solver need not pass over them
  // for it (a pass over a large body's positions costs a solve about 1.3 ns
  // a vertex, more than the rest of its solve: docs/performance.md). It
  // must be of the positions as given (results are then the same as
  // without it); the solver checks a few of them against it and throws
  // Error if one lies outside. Used whenever given, whether or not the
  // rotation is one.
  std::optional<PositionBounds> bounds;
};

// One object as the solver sees it: shared immutable topology and the current
// positions (#V x 3, world frame, metres), which must outlive Solve().
struct CollisionObject {
  const TetMesh* mesh = nullptr;
  const Positions* positions = nullptr;
  bool rigid = false;           // rigid objects never collide with each other
  bool self_collision = false;  // test the object's vertices against its own tets
  // The positions are those of the previous Solve() of this solver (same
  // object index, mesh and positions storage): a body that does not move,
  // such as a geom of MuJoCo's world body. The solver then keeps the
  // object's box and a tree over its chunks of tetrahedra from one solve to
  // the next, and passes over only the chunks and faces near its partners,
  // so that a large fixed body costs a solve about what its contacts cost.
  // Results are the same as without the flag. (A few vertices are compared
  // with the kept copy every solve: if they moved, the object is taken as
  // not fixed for that solve.)
  bool fixed = false;
  // Optional (when not fixed), must outlive Solve(): the object moves
  // rigidly, its positions are `frame` applied to body-frame positions that
  // do not change from one solve to the next (same object index, mesh and
  // positions storage), such as a proxy of a moving MuJoCo body. The solver
  // then keeps a tree over the object's chunks in the body frame, as for a
  // fixed object, and passes over only the chunks and faces near its
  // partners, and over its positions once for its box unless the frame
  // gives it (RigidFrame::bounds). Results are the
  // same as without the frame. The rotation must be orthonormal (to
  // rounding), else the frame is not used. (A few vertices are compared
  // with their kept body-frame positions every solve: if they moved by
  // more than rounding, the object is solved without its frame that solve.)
  const RigidFrame* frame = nullptr;
};

// Throws Error if object o's RigidFrame::bounds (given) leave out one of a
// few of its positions, spread over its numbering, the first and last among
// them.
void CheckGivenBounds(const CollisionObject& object, int o);

}  // namespace tetcosim
