#include "apps/cli_checks.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <optional>

#include "mesh/error.h"
#include "mujoco_bridge/world.h"

namespace tetcosim::app {
namespace {

// A validator that parses the value as a double and passes it to `ok`;
// `wanted` completes "must be ..." in the message.
CLI::Validator NumberCheck(bool (*ok)(double), const std::string& wanted, const std::string& name) {
  return CLI::Validator(
      [ok, wanted](std::string& text) -> std::string {
        // (strtod: beyond the range of double, such as 1e400, is infinite)
        char* end = nullptr;
        const double value = std::strtod(text.c_str(), &end);
        if (text.empty() || end != text.c_str() + text.size()) {
          return "'" + text + "' is not a number";
        }
        if (!ok(value)) return "'" + text + "' must be " + wanted;
        return {};
      },
      "FLOAT", name);
}

}  // namespace

CLI::Validator FiniteNumber() {
  return NumberCheck([](double x) { return std::isfinite(x); }, "a finite number", "FINITE");
}

CLI::Validator PositiveFiniteNumber() {
  return NumberCheck([](double x) { return std::isfinite(x) && x > 0.0; }, "a finite number > 0",
                     "POSITIVE");
}

CLI::Validator NonNegativeFiniteNumber() {
  return NumberCheck([](double x) { return std::isfinite(x) && x >= 0.0; }, "a finite number >= 0",
                     "NONNEGATIVE");
}

CLI::Validator StepNumber() {
  return CLI::Validator(
      [](std::string& text) -> std::string {
        const std::string wanted = "' must be a whole number from 1 to 2^53 (a count of steps)";
        if (text.empty() || text.size() > 16 ||
            !std::all_of(text.begin(), text.end(), [](char c) { return c >= '0' && c <= '9'; })) {
          return "'" + text + wanted;
        }
        const long long value = std::strtoll(text.c_str(), nullptr, 10);  // (16 digits fit)
        if (value < 1 || value > static_cast<long long>(kMaxWholeSteps)) return "'" + text + wanted;
        return {};
      },
      "STEPS", "STEPS");
}

long StepCount(double seconds, double dt, const std::string& option, bool warn) {
  const std::optional<long> steps = WholeSteps(seconds, dt);
  if (!steps) {
    char message[256];
    std::snprintf(message, sizeof(message),
                  "%s %g s is %g steps of %g s, more than 2^53 (%.3g); give a shorter time",
                  option.c_str(), seconds, std::round(seconds / dt), dt, kMaxWholeSteps);
    throw Error(message);
  }
  const long count = std::max(1L, *steps);
  const double simulated = static_cast<double>(count) * dt;
  if (warn && std::abs(simulated - seconds) > 1e-6 * dt) {
    std::fprintf(stderr,
                 "tetcosim: warning: %s %g s is not a whole number of %g s steps; running %ld "
                 "step%s (%g s)\n",
                 option.c_str(), seconds, dt, count, count == 1 ? "" : "s", simulated);
  }
  return count;
}

void PrintMeshWarnings(const TetMesh& mesh) {
  for (const std::string& warning : mesh.warnings()) {
    std::fprintf(stderr, "tetcosim: warning: %s: %s\n", mesh.source().c_str(), warning.c_str());
  }
}

void PrintLoadWarnings(const World& world) {
  for (const std::string& warning : world.load_warnings()) {
    std::fprintf(stderr, "tetcosim: warning: %s\n", warning.c_str());
  }
}

}  // namespace tetcosim::app
