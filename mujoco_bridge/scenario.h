#pragma once

// tetcosim::Scenario: a scripted rollout in a few lines, for GoogleTest
// scenario tests and small programs.
//
//   Scenario scenario("models/paper/cubes.xml");
//   ASSERT_TRUE(scenario.Run(0.2)) << scenario.message();
//   RolloutSummary summary = scenario.Summarize();
//   EXPECT_EQ(summary.pass_through_pairs, 0);
//
// Run() steps the world, calling the controller (if any) before each step and
// feeding every step to the RolloutMetrics; it stops early, returning false,
// when a step reports a non-finite state or MuJoCo's failure (the world, and
// Summarize(), then hold the state of the last step done: World::Step undoes
// the step).

#include <functional>
#include <memory>
#include <string>

#include "mujoco_bridge/rollout_metrics.h"
#include "mujoco_bridge/world.h"

namespace tetcosim {

class Scenario {
 public:
  explicit Scenario(const std::string& scene_path, const WorldOptions& options = {},
                    const RolloutMetricsOptions& metrics_options = {});

  // Simulates `duration` seconds (rounded to whole steps; throws Error for a
  // duration that is not finite, negative, or more than 2^53 steps).
  // `each_step`, when given, is called after every step (e.g. to record a
  // trajectory).
  bool Run(double duration, const std::function<void(World&)>& each_step = {});
  // Steps until `done(world)` holds (checked after each step) or `max_duration`
  // has passed; true if `done` held.
  bool RunUntil(const std::function<bool(const World&)>& done, double max_duration);
  // Called before every step: set controls, apply forces.
  void SetController(std::function<void(World&)> controller) {
    world_->SetController(std::move(controller));
  }

  World& world() { return *world_; }
  const RolloutMetrics& metrics() const { return *metrics_; }
  RolloutSummary Summarize() { return metrics_->Summarize(*world_); }
  bool ok() const { return message_.empty(); }
  // Why the last Run() or RunUntil() stopped early (empty if it did not).
  const std::string& message() const { return message_; }

 private:
  bool Advance();
  std::unique_ptr<World> world_;
  std::unique_ptr<RolloutMetrics> metrics_;
  std::string message_;
};

}  // namespace tetcosim
