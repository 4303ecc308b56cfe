#include "mujoco_bridge/scenario.h"

#include <cmath>

namespace tetcosim {

Scenario::Scenario(const std::string& scene_path, const WorldOptions& options,
                   const RolloutMetricsOptions& metrics_options)
    : world_(World::Load(scene_path, options)),
      metrics_(std::make_unique<RolloutMetrics>(*world_, metrics_options)) {}

bool Scenario::Advance() {
  world_->Step();
  if (world_->metrics().status != StepStatus::kOk) {
    message_ = world_->metrics().message;
    return false;
  }
  metrics_->Observe(*world_);
  return true;
}

bool Scenario::Run(double duration, const std::function<void(World&)>& each_step) {
  const long steps = std::lround(duration / world_->timestep());
  for (long s = 0; s < steps; ++s) {
    if (!Advance()) return false;
    if (each_step) each_step(*world_);
  }
  return true;
}

bool Scenario::RunUntil(const std::function<bool(const World&)>& done, double max_duration) {
  const long steps = std::lround(max_duration / world_->timestep());
  for (long s = 0; s < steps; ++s) {
    if (!Advance()) return false;
    if (done(*world_)) return true;
  }
  return false;
}

}  // namespace tetcosim
