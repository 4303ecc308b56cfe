// The closest-feature baseline (method = closest) and the fallback for
// colliding points with no border point: the nearest point of the
// penetrated surface.

#include "collision/penetration.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "collision/geometry.h"
#include "collision/penetration_internal.h"
#include "collision/simd4.h"
#include "mesh/parallel_for.h"

namespace tetcosim {
namespace {

// Closest features search a larger object through a box tree when it has
// at least this many queries in a solve, else all its triangles (building
// a tree costs about as much as 1.5 searches of every triangle: 15 to 19 ns
// per triangle against 12).
constexpr int kMinTreeQueries = 2;

}  // namespace

bool PenetrationSolver::ClosestSurfacePoint(std::span<const CollisionObject> objects, int b,
                                            const Eigen::Vector3d& p, int exclude,
                                            Eigen::Vector3d& closest) const {
  const Triangles& surface = objects[b].mesh->surface();
  double best = std::numeric_limits<double>::infinity();
  int best_face = -1;
  // (of triangles equally near, the lowest face: the result does not
  // depend on the order the search meets them in, the tree's)
  // face f with box [lo, hi]; corners() gives its corners
  // (box_point: p in the frame of the box, the body frame of a framed
  // object's kept boxes)
  auto test_face = [&](int f, const Eigen::Vector3d& lo, const Eigen::Vector3d& hi,
                       const Eigen::Vector3d& box_point, auto&& corners) {
    // (a triangle whose box is farther than the best cannot be nearer: on
    // a coarse box pressed into a fine body, most queries test every one
    // of its large faces)
    if (BoxDistance2(lo, hi, box_point) > best) return;
    if (exclude >= 0 &&
        (surface(f, 0) == exclude || surface(f, 1) == exclude || surface(f, 2) == exclude)) {
      return;
    }
    const std::array<Eigen::Vector3d, 3> corner = corners();
    Eigen::Vector3d c = ClosestPointOnTriangle(p, corner[0], corner[1], corner[2]);
    double d = (c - p).squaredNorm();
    if (d < best || (d == best && f < best_face)) {
      best = d;
      best_face = f;
      closest = c;
    }
  };
  // face f's corners from the object's positions (a small or kept object's
  // faces have no entry)
  const Positions& x = *objects[b].positions;
  auto face_corners = [&](int f) {
    return std::array<Eigen::Vector3d, 3>{x.row(surface(f, 0)).transpose(),
                                          x.row(surface(f, 1)).transpose(),
                                          x.row(surface(f, 2)).transpose()};
  };
  auto test = [&](int index) {  // a triangle entry
    const Surfaces::Entry& entry = surfaces_.entry(index);
    test_face(entry.face, entry.lo, entry.hi, p, [&] {
      const Surfaces::Geometry& triangle = surfaces_.geometry(index);
      return std::array<Eigen::Vector3d, 3>{triangle.corner[0], triangle.corner[1],
                                            triangle.corner[2]};
    });
  };
  if (surfaces_.small(b)) {  // (its boxes in its groups, no entries)
    const Surfaces::SmallGroup* groups = surfaces_.groups(b);
    for (int f = 0; f < surfaces_.entry_end(b) - surfaces_.entry_begin(b); ++f) {
      const Surfaces::SmallGroup& group = groups[f / 4];
      const int lane = f % 4;
      test_face(f, Lane(group.lo, lane), Lane(group.hi, lane), p, [&] { return face_corners(f); });
    }
    return std::isfinite(best);
  }
  // the object's box tree over all its triangles: kept, if it is fixed or
  // framed, or built by ComputeClosest (nearer boxes first, those farther
  // than the best passed over); else every triangle
  if (kept_[b].active) {
    const KeptObject& kept = kept_[b];
    // (framed: distances are the same in the body frame, and the kept
    // boxes' growth covers the rounding of p taken there)
    const Eigen::Vector3d q = kept.ToBody(p);
    kept.faces.Nearest(q, best, [&](int f) {
      test_face(f, kept.face_lo[f], kept.face_hi[f], q, [&] { return face_corners(f); });
    });
  } else if (closest_queries_[b] >= kMinTreeQueries) {
    const Surfaces::Table& hashed = surfaces_.table(b);
    hashed.tree.Nearest(p, best, [&](int item) { test(hashed.tree_entry[item]); });
  } else {
    for (int entry = surfaces_.entry_begin(b); entry < surfaces_.entry_end(b); ++entry) test(entry);
    for (int entry = surfaces_.rest_begin(b); entry < surfaces_.rest_end(b); ++entry) test(entry);
  }
  return std::isfinite(best);
}

// closest features: for every point without a value (fallback) or all points
void PenetrationSolver::ComputeClosest(std::span<const CollisionObject> objects, bool all) {
  Clock::time_point start = Clock::now();
  const int num_hits = static_cast<int>(colliding_.hits().size());
  if (all) {
    depth_.resize(num_hits);
    direction_.resize(num_hits);
    source_.resize(num_hits);
    layer_.assign(num_hits, -1);
  }
  const DepthSource source = all ? DepthSource::kClosest : DepthSource::kFallback;
  frontier_.clear();  // (free after stage 4): the points without a value
  tree_objects_.clear();
  closest_queries_.assign(objects.size(), 0);
  for (int h = 0; h < num_hits; ++h) {
    if (layer_[h] >= 0) continue;
    frontier_.push_back(h);
    const int b = colliding_.hits()[h].penetrated;
    surfaces_.AddRemaining(objects, b, kept_[b], colliding_.outcodes(b));
    // a box tree for the objects with enough queries to pay for it (a
    // coarse box's one corner in a fine ball is cheaper searched whole)
    if (++closest_queries_[b] == kMinTreeQueries && !surfaces_.small(b) && !kept_[b].active) {
      tree_objects_.push_back(b);
    }
  }
  const int num_trees = static_cast<int>(tree_objects_.size());
  ParallelFor(
      ThreadsFor(options_.num_threads, num_trees, 1), 0, num_trees,
      [&](int i) { surfaces_.BuildTree(tree_objects_[i]); }, Schedule::kDynamic, 1);
  const int num_pending = static_cast<int>(frontier_.size());
  ParallelFor(
      ThreadsFor(options_.num_threads, num_pending, 16), 0, num_pending,
      [&](int i) {
        const int h = frontier_[i];
        const int g = colliding_.hits()[h].vertex;
        const int a = vertices_.object[g];
        const int b = colliding_.hits()[h].penetrated;
        const Eigen::Vector3d p = Position(g);
        Eigen::Vector3d closest;
        int exclude = a == b ? g - vertices_.offset[a] : -1;
        if (!ClosestSurfacePoint(objects, b, p, exclude, closest)) return;
        Eigen::Vector3d to_surface = closest - p;
        double distance = to_surface.norm();
        depth_[h] = distance;
        if (distance > 0.0) {
          direction_[h] = to_surface / distance;
        } else {
          // on the surface: the way out is B's outward normal there; take the
          // containing tet's centroid as the inside
          const auto tet = objects[b].mesh->tets().row(colliding_.hits()[h].tet);
          Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
          for (int c = 0; c < 4; ++c) {
            centroid += objects[b].positions->row(tet[c]).transpose() / 4.0;
          }
          Eigen::Vector3d out = p - centroid;
          direction_[h] =
              out.norm() > 0.0 ? Eigen::Vector3d(out.normalized()) : Eigen::Vector3d::UnitZ();
        }
        source_[h] = source;
        layer_[h] = std::numeric_limits<int>::max();
      },
      Schedule::kDynamic, 16);
  timings_.closest += SecondsSince(start);
}

}  // namespace tetcosim
