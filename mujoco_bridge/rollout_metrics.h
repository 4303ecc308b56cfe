#pragma once

// Collision-response quality of a rollout (issue 6; docs/results.md explains
// each figure). Observe() after every World::Step(), Summarize() whenever a
// figure is wanted; it does not disturb the rollout.
//
// Objects are numbered as in Interpenetration: deformable i is i, MuJoCo body
// b is D + b (all static geoms belong to body 0, the world). A pair's contact
// episode runs from the first step in which one object has a point inside the
// other to the first step in which neither has.
//
// pass-through: the approach direction of a pair is set at the start of an
//   episode, n0 = unit(c_a - c_b) with c the centres of mass (for a static
//   body: the mean contact point of that step). While the contact stays
//   shallow (the method's depth below sticking_fraction x thickness) n0
//   follows the pair, so objects rolling on each other keep their order. If
//   (c_a - c_b).n0 < 0 when the episode ends (or at Summarize() for an open
//   one), the centres swapped sides. The objects did, a pass-through, if
//   each has its centre inside itself (a deformable's in one of its
//   tetrahedra; rigid bodies are taken as such), or if one of them, a
//   deformable, lies wholly past the other's centre: every vertex x of a
//   has (x - c_b).n0 < 0, or every vertex of b (x - c_a).n0 > 0. (A soft
//   sheet draped over a post or a box has its centre in the air below the
//   post's top or the box's centre, but lies on it.) A pair that ends
//   deeper than pass_through_fraction x the thinner object's thickness
//   counts too.
// sticking: at Summarize(), pairs interpenetrating deeper than
//   sticking_fraction x the thinner object's thickness (for a deformable and a
//   rigid body: the deformable's, since a penalty contact's resting depth
//   scales with the soft side) while at rest relative
//   to each other: the distance between their centres changes slower than
//   rest_speed (a stuck pair may still drift or spin as one). Points inside
//   geoms count as those inside meshes: a geom's signed distance (the
//   closest feature) holds a body stuck inside a thin one as a mesh's does
//   (tests/scenarios/thin_wall_test.cc). Deep pairs that are still moving
//   are counted in interpenetrating_pairs.
// depths here are exact (World::MeasureInterpenetration: distance to the
//   penetrated surface), so both depth methods are judged by the same ruler.
//   They are the vertices' depths: two coarse bodies can be half inside
//   each other, edges through faces, with no vertex deep (two of the
//   paper's 20-tetrahedron spheres, centres 1.45 cm apart, a third of one's
//   volume in the other, the deepest vertex 2.4 mm).
// spatial consistency: mean angle between the directions of two colliding
//   vertices joined by a mesh edge, inside the same object, over all steps.
// temporal continuity: the change of a colliding vertex's direction from one
//   step to the next (same vertex, same penetrated object): max and mean.
// Spatial and temporal figures use the depth method's own directions, of
// the points inside meshes (deformables, proxies) only.

#include <Eigen/Core>
#include <map>
#include <string>
#include <unordered_map>
#include <vector>

#include "mujoco_bridge/world.h"

namespace tetcosim {

struct RolloutMetricsOptions {
  // Thresholds as fractions of the thinner object's thickness (the smallest
  // extent of its bounding box at rest; bodies without a proxy count as
  // infinitely thick).
  double pass_through_fraction = 0.3;
  double sticking_fraction = 0.05;
  // The scene is at rest when no deformable vertex and no point of a moving
  // rigid body moves faster than this (m/s; a rigid body's fastest point taken
  // as |v_com| + |omega| World::RigidBodyRadius, so that a wheel spinning in
  // place is not at rest); a pair is at rest when its centres of mass move
  // slower than this relative to each other.
  double rest_speed = 0.02;
};

struct PairEvent {
  std::string kind;  // "pass-through" or "sticking"
  int a = -1;        // objects (numbering above), a < b
  int b = -1;
  std::string name_a, name_b;
  double time = 0.0;       // s: when it was detected
  double depth = 0.0;      // m: exact interpenetration depth then
  double threshold = 0.0;  // m: the depth that counts (pass-through or sticking)
};

struct RolloutSummary {
  long steps = 0;
  double time = 0.0;
  int pass_through_pairs = 0;  // distinct pairs
  int sticking_pairs = 0;
  int interpenetrating_pairs = 0;  // deeper than the sticking threshold, at rest or not
  // the (up to) five pairs deepest inside each other at the end, deepest
  // relative to their sticking threshold first (kind "deepest")
  std::vector<PairEvent> deepest_pairs;
  std::vector<PairEvent> events;
  // exact interpenetration of the current state
  double residual_max_depth = 0.0;   // m
  double residual_mean_depth = 0.0;  // m, over the points inside another object
  int residual_points = 0;
  // spatial consistency (degrees) and how many edge pairs it averages
  double mean_neighbour_angle = 0.0;
  long neighbour_pairs = 0;
  // temporal continuity (degrees)
  double max_direction_change = 0.0;
  double mean_direction_change = 0.0;
  long direction_changes = 0;
  // points over all steps
  long colliding_points = 0;
  long fallback_points = 0;
  long unresolved_points = 0;   // no border point reached and no fallback
  double max_depth_seen = 0.0;  // m: largest depth the method reported
  // state
  double final_kinetic_energy = 0.0;  // J, deformables + rigid bodies
  double max_speed = 0.0;  // m/s: fastest vertex, or rigid body point (World::RigidBodyRadius)
  bool at_rest = false;
  // cost
  double collision_ms = 0.0;  // total
  double collision_us_per_point = 0.0;
};

// The fastest deformable vertex or moving rigid body centre of mass (m/s).
double MaxSpeed(const World& world);
// An object's thickness, as the thresholds take it: the smallest extent of
// the bounding box of its mesh's rest positions (m).
double Thickness(const TetMesh& mesh);

class RolloutMetrics {
 public:
  explicit RolloutMetrics(const World& world, const RolloutMetricsOptions& options = {});

  // After every Step() of `world`.
  void Observe(const World& world);
  // The figures so far; measures the current state's exact interpenetration.
  RolloutSummary Summarize(World& world) const;

  // Of the last observed step (degrees; 0 without data), for per-step output.
  double step_max_direction_change() const { return step_max_change_; }
  double step_mean_neighbour_angle() const { return step_mean_angle_; }

  const RolloutMetricsOptions& options() const { return options_; }
  std::string ObjectName(int object) const { return names_[object]; }
  double ObjectThickness(int object) const { return thickness_[object]; }

 private:
  struct Episode {
    Eigen::Vector3d n0 = Eigen::Vector3d::Zero();        // approach direction, a minus b
    Eigen::Vector3d anchor_a = Eigen::Vector3d::Zero();  // centre used for a static body
    Eigen::Vector3d anchor_b = Eigen::Vector3d::Zero();
    long last_step = -1;
  };
  Eigen::Vector3d Center(const World& world, int object, const Eigen::Vector3d& anchor) const;
  Eigen::Vector3d CenterVelocity(const World& world, int object) const;
  bool Flipped(const World& world, int a, int b, const Episode& episode) const;
  // Whether the centre of mass of `object` lies inside it: a deformable's in
  // one of its tetrahedra; a rigid body's, or a static one's, taken as so.
  bool CenterInside(const World& world, int object) const;
  // Whether `object` is a deformable whose every vertex x has
  // (x - point).direction < 0.
  bool WhollyPast(const World& world, int object, const Eigen::Vector3d& point,
                  const Eigen::Vector3d& direction) const;
  void AddEvent(const World& world, const std::string& kind, int a, int b, double depth,
                double threshold, std::vector<PairEvent>& events) const;

  RolloutMetricsOptions options_;
  int num_deformables_ = 0;
  std::vector<std::string> names_;               // per object
  std::vector<double> thickness_;                // per object, m
  std::vector<char> static_;                     // per object
  std::map<std::pair<int, int>, Episode> open_;  // ordered: deterministic
  std::vector<PairEvent> events_;
  // direction of each colliding (object, penetrated, vertex), this and last step
  std::unordered_map<unsigned long long, Eigen::Vector3d> directions_, previous_;
  unsigned long long num_collision_objects_ = 1;
  unsigned long long max_vertices_ = 1;
  long steps_ = 0;
  double angle_sum_ = 0.0;
  long angle_count_ = 0;
  double change_sum_ = 0.0;
  double change_max_ = 0.0;
  long change_count_ = 0;
  double step_max_change_ = 0.0;
  double step_mean_angle_ = 0.0;
  long colliding_ = 0;
  long fallback_ = 0;
  long unresolved_ = 0;
  double max_depth_ = 0.0;
  double collision_ms_ = 0.0;
};

}  // namespace tetcosim
