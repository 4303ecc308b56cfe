#pragma once

// RolloutSummary, MuJoCo's warnings and a step's status as summary.json
// gives them, shared by `tetcosim run` and `tetcosim compare`.

#include <nlohmann/json.hpp>

#include "mujoco_bridge/rollout_metrics.h"

namespace tetcosim::app {

// A run's status for the step that stopped it (not kOk).
inline const char* StoppedStatusName(StepStatus status) {
  return status == StepStatus::kFailed ? "failed" : "diverged";
}

// World::MuJoCoWarnings() as summary.json's `mujoco_warnings`.
inline nlohmann::ordered_json MuJoCoWarningsJson(
    const std::vector<World::MuJoCoWarning>& warnings) {
  nlohmann::ordered_json array = nlohmann::ordered_json::array();
  for (const World::MuJoCoWarning& warning : warnings) {
    array.push_back({{"warning", warning.what}, {"count", warning.count}});
  }
  return array;
}

inline nlohmann::ordered_json MetricsJson(const RolloutSummary& s,
                                          const RolloutMetricsOptions& options) {
  auto pairs = [](const std::vector<PairEvent>& list) {
    nlohmann::ordered_json array = nlohmann::ordered_json::array();
    for (const PairEvent& e : list) {
      array.push_back({{"kind", e.kind},
                       {"a", e.name_a},
                       {"b", e.name_b},
                       {"time", e.time},
                       {"depth", e.depth},
                       {"threshold", e.threshold}});
    }
    return array;
  };
  return {{"pass_through_pairs", s.pass_through_pairs},
          {"sticking_pairs", s.sticking_pairs},
          {"interpenetrating_pairs", s.interpenetrating_pairs},
          {"events", pairs(s.events)},
          {"deepest_pairs", pairs(s.deepest_pairs)},
          {"residual_max_depth", s.residual_max_depth},
          {"residual_mean_depth", s.residual_mean_depth},
          {"residual_points", s.residual_points},
          {"mean_neighbour_angle_deg", s.mean_neighbour_angle},
          {"neighbour_pairs", s.neighbour_pairs},
          {"max_direction_change_deg", s.max_direction_change},
          {"mean_direction_change_deg", s.mean_direction_change},
          {"colliding_points", s.colliding_points},
          {"fallback_points", s.fallback_points},
          {"unresolved_points", s.unresolved_points},
          {"max_depth_seen", s.max_depth_seen},
          {"final_kinetic_energy", s.final_kinetic_energy},
          {"max_speed", s.max_speed},
          {"at_rest", s.at_rest},
          {"collision_us_per_point", s.collision_us_per_point},
          {"thresholds",
           {{"pass_through_fraction", options.pass_through_fraction},
            {"sticking_fraction", options.sticking_fraction},
            {"rest_speed", options.rest_speed}}}};
}

}  // namespace tetcosim::app
