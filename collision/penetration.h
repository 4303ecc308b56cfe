#pragma once

// Consistent penetration depth (Heidelberger, Teschner, Keiser, Muller,
// Gross, VMV 2004; see docs/collision.md and ../shared/docs/method.md) and
// the closest-feature baseline, for N tetrahedral collision objects.
//
// For every vertex p of object A that lies inside object B (A != B, or A == B
// with self-collision on and p not a vertex of B's containing tetrahedron),
// the solver returns one PenetrationResult: depth d >= 0, unit direction r
// (the way out of B), B's containing tetrahedron and p's barycentric
// coordinates in it, and how the value was obtained.
//
// Consistent method, per step:
//   1. colliding points: vertices hashed by cell; every tetrahedron tests the
//      vertices in the cells its bounding box covers (colliding_points.h);
//   2. border points (colliding w.r.t. B with a neighbour that is not) and
//      their intersection edges: the crossing with B's surface nearest the
//      outside vertex q, and B's smooth normal there;
//   3. d(p) = sum_i w_i (x_i - p).n_i / sum_i w_i,
//      r(p) = normalise(sum_i w_i n_i),  w_i = 1 / |x_i - p|^2;
//   4. propagation, layer by layer from earlier layers only:
//      d(p) = sum_j mu_j ((p_j - p).r(p_j) + d(p_j)) / sum_j mu_j,
//      r(p) = normalise(sum_j mu_j r(p_j)),  mu_j = 1 / |p_j - p|^2.
//   Beyond the paper: points of a component with no border point get the
//   closest-feature value, flagged kFallback.
// Closest-feature method: d = distance to the nearest point of B's surface,
// r = unit vector from p toward it.
//
// Rigid-rigid pairs are skipped (the rigid engine handles them).
// Deterministic: bit-identical results for the same input whatever the
// thread count. No heap allocation per step once the buffers have grown to
// the scene's size.

#include <cstdint>
#include <span>
#include <vector>

#include "collision/broad_phase.h"
#include "collision/colliding_points.h"
#include "collision/collision_object.h"
#include "collision/kept_object.h"
#include "collision/surfaces.h"
#include "mesh/tet_mesh.h"

namespace tetcosim {

enum class DepthMethod { kConsistent, kClosest };

// How a result's depth and direction were obtained.
enum class DepthSource : std::uint8_t {
  kBorder,      // stage 3: from the point's own intersection edges
  kPropagated,  // stage 4: from neighbours, layer by layer
  kFallback,    // consistent method, no border point reached: closest feature
  kClosest,     // closest-feature method
};

const char* DepthMethodName(DepthMethod method);
const char* DepthSourceName(DepthSource source);

struct PenetrationResult {
  int object = -1;      // A: the object of the colliding vertex
  int vertex = -1;      // the vertex, index into A's mesh
  int penetrated = -1;  // B: the object it is inside
  int tet = -1;         // B's tetrahedron that contains the vertex
  Eigen::Vector4d barycentric = Eigen::Vector4d::Zero();  // of the vertex in that tet
  double depth = 0.0;                                     // >= 0, metres
  Eigen::Vector3d direction = Eigen::Vector3d::Zero();    // unit, out of B
  DepthSource source = DepthSource::kBorder;
};

struct PenetrationOptions {
  DepthMethod method = DepthMethod::kConsistent;
  // Hash cell size in metres (finite, >= 0); 0 picks the average edge
  // length over all objects (Teschner et al. 2003). A speed setting only:
  // results do not depend on it.
  double cell_size = 0.0;
  // Threads for the parallel stages (1 = serial). Results do not depend on it.
  int num_threads = 1;
  // Give points that no border point reaches the closest-feature value.
  bool fallback = true;
};

// Wall-clock seconds spent in each stage of the last Solve().
struct PenetrationTimings {
  double hash = 0.0;       // stage 1a: broad phase and hashing vertices
  double inside = 0.0;     // stage 1b: vertex-in-tetrahedron tests
  double surfaces = 0.0;   // penetrated objects' vertex normals and triangle hash
  double intersect = 0.0;  // stages 2 and 3: intersection edges against surfaces, and
                           // border points' depth and direction from their crossings
  double propagate = 0.0;  // stage 4: propagation
  double closest = 0.0;    // closest features (fallback or closest method)
  double total = 0.0;
};

struct PenetrationStats {
  int colliding = 0;   // results
  int border = 0;      // kBorder results
  int propagated = 0;  // kPropagated results
  int fallback = 0;    // kFallback results
  int closest = 0;     // kClosest results
  int unresolved = 0;  // colliding points that got no value (fallback off)
  int intersection_edges = 0;
  // the work behind them: vertex-in-tetrahedron tests (stage 1: barycentric
  // coordinates of a vertex found in a tetrahedron's box) and
  // segment-triangle tests (stage 2: an intersection edge against a
  // triangle whose box meets the edge's)
  std::int64_t tet_tests = 0;
  std::int64_t triangle_tests = 0;
  int layers = 0;  // propagation layers
  // objects left out of the solve for an infinite or NaN position (the
  // caller's state has diverged; the rest of the scene is solved as if
  // they were not there)
  int non_finite_objects = 0;
  // objects solved with what the solver kept of them (CollisionObject::fixed,
  // and they had not moved)
  int fixed_objects = 0;
  // the same for objects with a CollisionObject::frame, moved rigidly
  int framed_objects = 0;
  double max_depth = 0.0;
  double mean_depth = 0.0;
};

class PenetrationSolver {
 public:
  // Throws Error for a cell size that is negative, infinite or NaN.
  explicit PenetrationSolver(PenetrationOptions options = {});

  const PenetrationOptions& options() const { return options_; }
  void set_options(const PenetrationOptions& options);

  // Finds every colliding point and its depth and direction. Results are
  // ordered by (object, vertex, penetrated). The returned reference stays
  // valid until the next Solve(). Throws Error for an object without a mesh
  // or positions, or with a number of positions other than its vertices'.
  const std::vector<PenetrationResult>& Solve(std::span<const CollisionObject> objects);

  const std::vector<PenetrationResult>& results() const { return results_; }
  const PenetrationTimings& timings() const { return timings_; }
  const PenetrationStats& stats() const { return stats_; }
  double cell_size() const { return cell_size_; }
  // The average edge length over the objects of the last Solve() (1 m if
  // none has edges): lengths that tell points apart (a point on a surface,
  // two coincident points) are relative to it, never to the cell size.
  double length_scale() const { return length_scale_; }

 private:
  using Hit = CollidingPoints::Hit;
  // What one thread of the surfaces and stages 2 to 4 writes, on cache
  // lines of its own (as CollidingPoints' threads do: neighbouring threads'
  // vector headers in a plain array would share a line, which every
  // push_back would take away from the other core)
  struct alignas(64) ThreadScratch {
    std::vector<int> faces;           // surfaces: an object's faces in play
    std::vector<std::uint32_t> seen;  // stage 2: per triangle entry, the query
                                      // in which it was last tested
    std::uint32_t query = 0;
    int edges = 0;                    // stage 2: intersection edges met
    std::int64_t triangle_tests = 0;  // stage 2: PenetrationStats::triangle_tests
    std::vector<int> candidates;      // stage 4: points next to the layer's points,
                                      // for the next layer (the first: listed in stage 2)
  };

  void Prepare(std::span<const CollisionObject> objects);
  // stage 1 overlapped with the surfaces of every object with a partner
  void FindCollidingPointsAndHashSurfaces(std::span<const CollisionObject> objects, int threads);
  // the surfaces of the objects that may be penetrated (surface_list_;
  // with full, every face of those not kept, for the closest method), and
  // their vertex normals
  void HashSurfaces(std::span<const CollisionObject> objects, bool full);
  // Surfaces::Make of object o on the calling thread
  void MakeSurface(std::span<const CollisionObject> objects, int o);
  // stages 2 and 3: intersection edges, their crossings, border points
  void ComputeBorderPoints(std::span<const CollisionObject> objects);
  void Propagate(std::span<const CollisionObject> objects);
  void ComputeClosest(std::span<const CollisionObject> objects, bool all);
  void CollectResults(std::span<const CollisionObject> objects);

  // (inline: stages 2 and 4 call these for every neighbour of a point)
  int FindHit(int vertex, int penetrated) const { return colliding_.FindHit(vertex, penetrated); }
  Eigen::Vector3d Position(int global_vertex) const { return vertices_.Position(global_vertex); }
  // nearest point of B's surface to p (excluding triangles at vertex
  // `exclude` of B, or -1); returns false if B has no usable triangle
  bool ClosestSurfacePoint(std::span<const CollisionObject> objects, int b,
                           const Eigen::Vector3d& p, int exclude, Eigen::Vector3d& closest) const;

  PenetrationOptions options_;
  double cell_size_ = 1.0;     // of every hash (vertices, each object's triangles), metres
  double length_scale_ = 1.0;  // the objects' average edge length, metres
  int max_degree_ = 0;         // the most neighbours of a vertex in the objects

  GlobalVertices vertices_;
  // broad phase: per object its current (inflated) bounding box, and its
  // partners and search box
  std::vector<BroadPhaseBox> boxes_;  // #objects
  BroadPhase broad_phase_;
  std::vector<KeptObject> kept_;               // #objects
  CollidingPoints colliding_;                  // stage 1
  std::vector<ThreadScratch> thread_scratch_;  // #threads

  // the surfaces: those of the objects in surface_list_, the penetrated
  // ones, or every one with a partner when stage 1 and the surfaces share a
  // region
  Surfaces surfaces_;
  std::vector<char> object_penetrated_;  // #objects
  std::vector<int> surface_list_;
  std::vector<int> tree_objects_;     // the objects whose box trees a solve builds
  std::vector<int> closest_queries_;  // #objects: closest-feature queries into it (a box tree
                                      // from kMinTreeQueries, small objects aside)

  // stage 2 on several threads: the hits grouped by the thread that made
  // their penetrated object's entries, and the groups' offsets
  std::vector<int> hit_order_, hit_group_offset_;

  // per hit: value and state
  std::vector<double> depth_;
  std::vector<Eigen::Vector3d> direction_;
  std::vector<DepthSource> source_;
  std::vector<int> layer_;  // -1: no value yet; 0 border; k propagated in layer k
  std::vector<int> frontier_, next_frontier_;

  std::vector<PenetrationResult> results_;
  PenetrationTimings timings_;
  PenetrationStats stats_;
};

}  // namespace tetcosim
