#include "mujoco_bridge/rollout_metrics.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <set>

#include "collision/geometry.h"

namespace tetcosim {
namespace {

constexpr double kDegrees = 180.0 / 3.14159265358979323846;

double AngleDegrees(const Eigen::Vector3d& u, const Eigen::Vector3d& v) {
  return std::acos(std::clamp(u.dot(v), -1.0, 1.0)) * kDegrees;
}

}  // namespace

double Thickness(const TetMesh& mesh) {
  const Positions& x = mesh.positions();
  return (x.colwise().maxCoeff() - x.colwise().minCoeff()).minCoeff();
}

double MaxSpeed(const World& world) {
  double speed = 0.0;
  for (int i = 0; i < world.num_deformables(); ++i) {
    const Positions& v = world.deformable(i).velocities();
    if (v.rows() > 0) speed = std::max(speed, v.rowwise().norm().maxCoeff());
  }
  for (int b = 1; b < world.num_rigid_bodies(); ++b) {
    if (world.RigidBodyIsStatic(b)) continue;
    // its fastest point: a body spinning in place is not at rest
    const double centre = world.RigidBodyPointVelocity(b, world.RigidBodyCenterOfMass(b)).norm();
    speed = std::max(speed,
                     centre + world.RigidBodyAngularVelocity(b).norm() * world.RigidBodyRadius(b));
  }
  return speed;
}

RolloutMetrics::RolloutMetrics(const World& world, const RolloutMetricsOptions& options)
    : options_(options), num_deformables_(world.num_deformables()) {
  const int num_objects = num_deformables_ + world.num_rigid_bodies();
  names_.resize(num_objects);
  thickness_.assign(num_objects, std::numeric_limits<double>::infinity());
  static_.assign(num_objects, 0);
  for (int i = 0; i < num_deformables_; ++i) {
    names_[i] = world.deformable(i).name();
    thickness_[i] = Thickness(world.deformable(i).mesh());
  }
  for (int b = 0; b < world.num_rigid_bodies(); ++b) {
    names_[num_deformables_ + b] = b == 0 ? std::string("world") : world.RigidBodyName(b);
    static_[num_deformables_ + b] = world.RigidBodyIsStatic(b) ? 1 : 0;
  }
}

Eigen::Vector3d RolloutMetrics::Center(const World& world, int object,
                                       const Eigen::Vector3d& anchor) const {
  if (object < num_deformables_) return world.deformable(object).CenterOfMass();
  if (static_[object]) return anchor;
  return world.RigidBodyCenterOfMass(object - num_deformables_);
}

Eigen::Vector3d RolloutMetrics::CenterVelocity(const World& world, int object) const {
  if (object < num_deformables_) return world.deformable(object).CenterOfMassVelocity();
  const int b = object - num_deformables_;
  if (static_[object]) return Eigen::Vector3d::Zero();
  return world.RigidBodyPointVelocity(b, world.RigidBodyCenterOfMass(b));
}

bool RolloutMetrics::CenterInside(const World& world, int object) const {
  if (object >= num_deformables_) return true;
  const DeformableBody& body = world.deformable(object);
  const Eigen::Vector3d p = body.CenterOfMass();
  const Positions& x = body.positions();
  const Tets& tets = body.mesh().tets();
  for (int t = 0; t < tets.rows(); ++t) {
    Eigen::Vector4d l;  // (inverted tetrahedra too: the coordinates do not depend on the sign)
    if (TetBarycentric(x.row(tets(t, 0)), x.row(tets(t, 1)), x.row(tets(t, 2)), x.row(tets(t, 3)),
                       p, l) &&
        l.minCoeff() >= 0.0) {
      return true;
    }
  }
  return false;
}

bool RolloutMetrics::WhollyPast(const World& world, int object, const Eigen::Vector3d& point,
                                const Eigen::Vector3d& direction) const {
  if (object >= num_deformables_) return false;
  const Positions& x = world.deformable(object).positions();
  return x.rows() > 0 && ((x.rowwise() - point.transpose()) * direction).maxCoeff() < 0.0;
}

bool RolloutMetrics::Flipped(const World& world, int a, int b, const Episode& episode) const {
  if (episode.n0.isZero()) return false;
  const Eigen::Vector3d center_a = Center(world, a, episode.anchor_a);
  const Eigen::Vector3d center_b = Center(world, b, episode.anchor_b);
  if ((center_a - center_b).dot(episode.n0) >= 0.0) return false;
  // the centres swapped sides; so did the objects if both are compact (their
  // centres inside them), or one lies wholly past the other's centre (a
  // sheet draped over a post, its centre in the air below the post's top,
  // lies on it)
  return (CenterInside(world, a) && CenterInside(world, b)) ||
         WhollyPast(world, a, center_b, episode.n0) || WhollyPast(world, b, center_a, -episode.n0);
}

void RolloutMetrics::AddEvent(const World& world, const std::string& kind, int a, int b,
                              double depth, double threshold,
                              std::vector<PairEvent>& events) const {
  events.push_back({kind, a, b, names_[a], names_[b], world.time(), depth, threshold});
}

void RolloutMetrics::Observe(const World& world) {
  ++steps_;
  const std::vector<PenetrationResult>& results = world.penetrations();
  const std::vector<ContactPoint>& contacts = world.contacts();
  const std::vector<int>& rigid = world.contact_rigid_bodies();
  const std::vector<CollisionObject>& objects = world.collision_objects();
  if (steps_ == 1) {
    // proxies: a rigid body is as thin as its thinnest proxy
    for (int p = 0; p < world.num_proxies(); ++p) {
      int object = num_deformables_ + world.ProxyBody(p);
      thickness_[object] =
          std::min(thickness_[object], Thickness(*objects[num_deformables_ + p].mesh));
    }
    // (collision object, penetrated object, vertex) -> one key, without
    // overflow below 2^64 = (objects^2 x vertices of the largest mesh)
    num_collision_objects_ = objects.size();
    max_vertices_ = 1;
    for (const CollisionObject& object : objects) {
      max_vertices_ = std::max<unsigned long long>(max_vertices_, object.mesh->num_vertices());
    }
  }
  auto DirectionKey = [&](int object, int penetrated, int vertex) {
    return (static_cast<unsigned long long>(object) * num_collision_objects_ +
            static_cast<unsigned long long>(penetrated)) *
               max_vertices_ +
           static_cast<unsigned long long>(vertex);
  };

  // pairs in contact this step: sum of their contact points, deepest point
  struct Seen {
    Eigen::Vector3d point_sum = Eigen::Vector3d::Zero();
    int points = 0;
    double depth = 0.0;
  };
  std::map<std::pair<int, int>, Seen> seen;
  for (size_t k = 0; k < contacts.size(); ++k) {
    int inside, penetrated;
    Eigen::Vector3d point;
    if (k < results.size()) {
      const PenetrationResult& r = results[k];
      inside = world.MetricObject(r.object);
      penetrated = world.MetricObject(r.penetrated);
      point = objects[r.object].positions->row(r.vertex).transpose();
    } else {
      inside = contacts[k].body_a;
      penetrated = num_deformables_ + rigid[k];
      point = world.deformable(inside).positions().row(contacts[k].vertex_a).transpose();
    }
    if (inside == penetrated) continue;  // self-contact has no order
    Seen& entry = seen[{std::min(inside, penetrated), std::max(inside, penetrated)}];
    entry.point_sum += point;
    ++entry.points;
    entry.depth = std::max(entry.depth, contacts[k].depth);
  }
  for (const auto& [pair, contact] : seen) {
    auto found = open_.find(pair);
    if (found != open_.end()) {
      Episode& episode = found->second;
      episode.last_step = steps_;
      // while the contact is shallow the objects cannot have swapped sides:
      // follow the pair's direction (objects rolling on each other), unless
      // it has already turned by more than 90 degrees
      const double thickness = std::min(thickness_[pair.first], thickness_[pair.second]);
      if (contact.depth < options_.sticking_fraction * thickness) {
        Episode next = episode;
        next.anchor_a = next.anchor_b = contact.point_sum / contact.points;
        Eigen::Vector3d d =
            Center(world, pair.first, next.anchor_a) - Center(world, pair.second, next.anchor_b);
        if (d.norm() > 0.0 && d.dot(episode.n0) > 0.0) {
          next.n0 = d.normalized();
          episode = next;
        }
      }
      continue;
    }
    // a new episode: the approach direction from the centres
    Episode episode;
    episode.anchor_a = episode.anchor_b = contact.point_sum / contact.points;
    Eigen::Vector3d d =
        Center(world, pair.first, episode.anchor_a) - Center(world, pair.second, episode.anchor_b);
    if (d.norm() > 0.0) episode.n0 = d.normalized();
    episode.last_step = steps_;
    open_.emplace(pair, episode);
  }
  // episodes that ended: did the objects swap sides?
  for (auto it = open_.begin(); it != open_.end();) {
    if (it->second.last_step == steps_) {
      ++it;
      continue;
    }
    if (Flipped(world, it->first.first, it->first.second, it->second)) {
      AddEvent(world, "pass-through", it->first.first, it->first.second, 0.0, 0.0, events_);
    }
    it = open_.erase(it);
  }

  // spatial consistency (edges of colliding vertices) and temporal continuity
  directions_.clear();
  for (const PenetrationResult& r : results) {
    directions_[DirectionKey(r.object, r.penetrated, r.vertex)] = r.direction;
  }
  double step_angle_sum = 0.0;
  long step_angle_count = 0;
  step_max_change_ = 0.0;
  for (const PenetrationResult& r : results) {
    const TetMesh& mesh = *objects[r.object].mesh;
    const int begin = mesh.adjacency_offsets()[r.vertex];
    const int end = mesh.adjacency_offsets()[r.vertex + 1];
    for (int k = begin; k < end; ++k) {
      const int w = mesh.adjacency()[k];
      if (w <= r.vertex) continue;
      auto neighbour = directions_.find(DirectionKey(r.object, r.penetrated, w));
      if (neighbour == directions_.end()) continue;
      step_angle_sum += AngleDegrees(r.direction, neighbour->second);
      ++step_angle_count;
    }
    auto before = previous_.find(DirectionKey(r.object, r.penetrated, r.vertex));
    if (before != previous_.end()) {
      double change = AngleDegrees(r.direction, before->second);
      step_max_change_ = std::max(step_max_change_, change);
      change_sum_ += change;
      ++change_count_;
    }
  }
  angle_sum_ += step_angle_sum;
  angle_count_ += step_angle_count;
  step_mean_angle_ =
      step_angle_count > 0 ? step_angle_sum / static_cast<double>(step_angle_count) : 0.0;
  change_max_ = std::max(change_max_, step_max_change_);
  std::swap(directions_, previous_);

  const StepMetrics& metrics = world.metrics();
  colliding_ += metrics.colliding_points;
  fallback_ += metrics.fallback_points;
  unresolved_ += metrics.unresolved_points;
  max_depth_ = std::max(max_depth_, metrics.max_depth);
  collision_ms_ += metrics.collision_ms;
}

RolloutSummary RolloutMetrics::Summarize(World& world) const {
  RolloutSummary s;
  s.steps = steps_;
  s.time = world.time();
  s.events = events_;
  for (const auto& [pair, episode] : open_) {
    if (Flipped(world, pair.first, pair.second, episode)) {
      AddEvent(world, "pass-through", pair.first, pair.second, 0.0, 0.0, s.events);
    }
  }

  // exact interpenetration of the current state, deepest per pair; a static
  // body's centre is where the pair's points are
  std::map<std::pair<int, int>, double> deepest;
  std::map<std::pair<int, int>, Eigen::Vector3d> anchor;
  double depth_sum = 0.0;
  for (const Interpenetration& point : world.MeasureInterpenetration()) {
    s.residual_max_depth = std::max(s.residual_max_depth, point.depth);
    depth_sum += point.depth;
    ++s.residual_points;
    if (point.inside == point.penetrated) continue;
    const std::pair<int, int> pair(std::min(point.inside, point.penetrated),
                                   std::max(point.inside, point.penetrated));
    double& depth = deepest[pair];
    depth = std::max(depth, point.depth);
    anchor.emplace(pair, point.point);
  }
  if (s.residual_points > 0) s.residual_mean_depth = depth_sum / s.residual_points;
  std::set<std::pair<int, int>> passed;
  for (const PairEvent& event : s.events) passed.insert({event.a, event.b});
  std::vector<PairEvent> ranked;
  for (const auto& [pair, depth] : deepest) {
    // (pair copied in: clang before 16 cannot capture a structured binding)
    auto world_centre = [&, key = pair](int object) {
      return Center(world, object, anchor.at(key));
    };
    const double thickness = std::min(thickness_[pair.first], thickness_[pair.second]);
    if (depth > options_.pass_through_fraction * thickness && !passed.count(pair)) {
      AddEvent(world, "pass-through", pair.first, pair.second, depth,
               options_.pass_through_fraction * thickness, s.events);
      passed.insert(pair);
    }
    // a penalty contact's resting depth scales with the soft side: measure a
    // soft-rigid pair by the deformable
    const double soft_thickness = pair.second < num_deformables_
                                      ? thickness
                                      : thickness_[pair.first];  // pair.first < pair.second
    ranked.push_back({"deepest", pair.first, pair.second, names_[pair.first], names_[pair.second],
                      world.time(), depth, options_.sticking_fraction * soft_thickness});
    if (depth > options_.sticking_fraction * soft_thickness) {
      ++s.interpenetrating_pairs;
      // at rest relative to each other: the distance between the centres
      // does not change (a pair stuck together may still spin as one)
      Eigen::Vector3d d = world_centre(pair.first) - world_centre(pair.second);
      const double separation_speed =
          d.norm() > 0.0 ? (CenterVelocity(world, pair.first) - CenterVelocity(world, pair.second))
                               .dot(d.normalized())
                         : 0.0;
      if (std::abs(separation_speed) < options_.rest_speed) {
        AddEvent(world, "sticking", pair.first, pair.second, depth,
                 options_.sticking_fraction * soft_thickness, s.events);
        ++s.sticking_pairs;
      }
    }
  }
  s.pass_through_pairs = static_cast<int>(passed.size());
  std::stable_sort(ranked.begin(), ranked.end(), [](const PairEvent& x, const PairEvent& y) {
    return x.depth * y.threshold > y.depth * x.threshold;
  });
  if (ranked.size() > 5) ranked.resize(5);
  s.deepest_pairs = ranked;

  s.mean_neighbour_angle = angle_count_ > 0 ? angle_sum_ / static_cast<double>(angle_count_) : 0.0;
  s.neighbour_pairs = angle_count_;
  s.max_direction_change = change_max_;
  s.mean_direction_change =
      change_count_ > 0 ? change_sum_ / static_cast<double>(change_count_) : 0.0;
  s.direction_changes = change_count_;
  s.colliding_points = colliding_;
  s.fallback_points = fallback_;
  s.unresolved_points = unresolved_;
  s.max_depth_seen = max_depth_;

  s.final_kinetic_energy = world.DeformableKineticEnergy() + world.RigidKineticEnergy();
  s.max_speed = MaxSpeed(world);
  s.at_rest = s.max_speed < options_.rest_speed;
  s.collision_ms = collision_ms_;
  s.collision_us_per_point =
      colliding_ > 0 ? collision_ms_ * 1e3 / static_cast<double>(colliding_) : 0.0;
  return s;
}

}  // namespace tetcosim
