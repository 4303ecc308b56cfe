#pragma once

// The subcommands of the tetcosim command line; each adds itself to the app
// and runs from its callback. Errors in user input are thrown as
// tetcosim::Error and turned into a message and exit code 1 by main.

#include <CLI/CLI.hpp>

namespace tetcosim::app {

void AddInfoCommand(CLI::App& app);
void AddDepthCommand(CLI::App& app);
void AddRunCommand(CLI::App& app);
void AddCheckCommand(CLI::App& app);
void AddCompareCommand(CLI::App& app);

}  // namespace tetcosim::app
