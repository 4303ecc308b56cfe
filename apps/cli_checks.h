#pragma once

// Checks of command-line values that the subcommands share. CLI11's
// PositiveNumber and NonNegativeNumber let NaN through (every comparison
// with it is false, so `--duration nan` ran the default second) and answer
// infinity with the whole range of double; these reject both in one line.

#include <CLI/CLI.hpp>
#include <string>

namespace tetcosim::app {

// A finite number ("nan" and "inf" are errors).
CLI::Validator FiniteNumber();
// A finite number > 0.
CLI::Validator PositiveFiniteNumber();
// A finite number >= 0.
CLI::Validator NonNegativeFiniteNumber();

// The number of steps of dt (seconds, > 0) in `seconds` (> 0), rounded to
// the nearest and at least 1. Throws Error, naming `option`, when that is
// more than 2^53 steps (where the count stops being exact in a double, and
// far beyond any run that could end).
long StepCount(double seconds, double dt, const std::string& option);

}  // namespace tetcosim::app
