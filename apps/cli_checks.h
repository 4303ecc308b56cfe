#pragma once

// Checks of command-line values, and the printing of loaded meshes' and
// scenes' warnings, that the subcommands share. CLI11's PositiveNumber and
// NonNegativeNumber let NaN through (every comparison with it is false, so
// `--duration nan` ran the default second) and answer infinity with the
// whole range of double; these reject both in one line.

#include <CLI/CLI.hpp>
#include <string>

#include "mujoco_bridge/world.h"

namespace tetcosim::app {

// A finite number ("nan" and "inf" are errors).
CLI::Validator FiniteNumber();
// A finite number > 0.
CLI::Validator PositiveFiniteNumber();
// A finite number >= 0.
CLI::Validator NonNegativeFiniteNumber();
// A whole number from 1 to 2^53 (kMaxWholeSteps), written in digits: a count
// of steps ("0", "-3", "1.5" and "1e20" are errors that say so, where CLI11's
// PositiveNumber printed the whole range of double).
CLI::Validator StepNumber();

// WholeSteps (mujoco_bridge/world.h), at least 1, for seconds > 0 that a
// command-line option gave: Error, naming `option`, when there are more than
// 2^53. When those steps do not make `seconds` (to a millionth of a step)
// and `warn`, a warning on stderr says what will run instead.
long StepCount(double seconds, double dt, const std::string& option, bool warn = true);

// Prints a mesh's warnings (TetMesh::warnings), each as "tetcosim: warning:
// <its source>: ...", to stderr.
void PrintMeshWarnings(const TetMesh& mesh);
// Prints a world's load warnings (World::load_warnings, which name the scene
// line, element and file), each as "tetcosim: warning: ...", to stderr.
void PrintLoadWarnings(const World& world);

}  // namespace tetcosim::app
