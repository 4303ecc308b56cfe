// tetcosim: soft tetrahedral bodies with MuJoCo rigid bodies and robots.

#include <cstdio>
#include <exception>

#include "apps/commands.h"
#include "mesh/error.h"
#include "mujoco_bridge/mujoco_version.h"

namespace {

int Main(CLI::App& app, int argc, char** argv) {
  app.set_version_flag("--version", [] {
    return std::string("tetcosim 0.1.0 (MuJoCo ") + tetcosim::MujocoVersion() + ")";
  });
  app.require_subcommand(1);
  tetcosim::app::AddInfoCommand(app);
  tetcosim::app::AddDepthCommand(app);
  tetcosim::app::AddRunCommand(app);
  tetcosim::app::AddCheckCommand(app);
  tetcosim::app::AddCompareCommand(app);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  // (everything in the try: setting the commands up may throw too)
  try {
    CLI::App app{
        "tetcosim: soft tetrahedral bodies (co-rotational FEM, consistent penetration "
        "depth) with MuJoCo rigid bodies and robots"};
    return Main(app, argc, argv);
  } catch (const tetcosim::Error& e) {
    std::fprintf(stderr, "tetcosim: error: %s\n", e.what());
    return 1;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "tetcosim: internal error: %s\n", e.what());
    return 3;
  }
}
