#include "mujoco_bridge/scenario.h"

#include <cmath>
#include <cstdio>
#include <optional>

#include "mesh/error.h"

namespace tetcosim {
namespace {

// The whole steps of dt in `duration`: an Error for a duration that is NaN,
// infinite, negative or more than 2^53 steps (rounding such a count to a
// long ran no step at all, and Run reported success).
long StepsIn(double duration, double dt, const char* caller) {
  const std::optional<long> steps = WholeSteps(duration, dt);
  if (!steps) {
    char message[160];
    std::snprintf(message, sizeof(message),
                  "Scenario::%s: a duration of %g s at steps of %g s; give a finite duration >= 0 "
                  "of at most 2^53 steps",
                  caller, duration, dt);
    throw Error(message);
  }
  return *steps;
}

}  // namespace

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
  const long steps = StepsIn(duration, world_->timestep(), "Run");
  message_.clear();
  for (long s = 0; s < steps; ++s) {
    if (!Advance()) return false;
    if (each_step) each_step(*world_);
  }
  return true;
}

bool Scenario::RunUntil(const std::function<bool(const World&)>& done, double max_duration) {
  const long steps = StepsIn(max_duration, world_->timestep(), "RunUntil");
  message_.clear();
  for (long s = 0; s < steps; ++s) {
    if (!Advance()) return false;
    if (done(*world_)) return true;
  }
  return false;
}

}  // namespace tetcosim
