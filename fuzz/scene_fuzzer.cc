// libFuzzer target for scenes: the input is the inside of a <deformable>
// element, put into a fixed MJCF world (a floor, a free box, a lid on a
// limited hinge, a free ball, a rod with a mesh geom, a mocap block), then
// loaded with World::Load and stepped a few times. An Error from loading,
// and a step status other than kOk, are correct answers to bad input; a
// crash, a hang, a leak or a sanitizer report is a bug.
//
// The scene is written to $TETCOSIM_FUZZ_DIR/scenes/fuzz.xml (scripts/fuzz
// links the bundled meshes at $TETCOSIM_FUZZ_DIR/meshes, so that
// file="../meshes/sphere.msh" reads one), or to a folder under the system's
// temporary one.

#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <string_view>

#include "mesh/error.h"
#include "mujoco_bridge/rollout_metrics.h"
#include "mujoco_bridge/world.h"

namespace {

constexpr std::string_view kBefore = R"(<mujoco>
  <option timestep="0.002"/>
  <asset><mesh name="tetra" vertex="0 0 0  0.1 0 0  0 0.1 0  0 0 0.1"/></asset>
  <worldbody>
    <geom name="floor" type="plane" size="1 1 0.1"/>
    <body name="box" pos="0 0 0.05">
      <freejoint/><geom name="box" type="box" size="0.15 0.15 0.05" mass="2"/>
    </body>
    <body name="lid" pos="0.5 0 0.2">
      <joint name="hinge" type="hinge" axis="0 1 0" range="-30 30" limited="true" damping="0.1"/>
      <geom name="lid" type="box" pos="0.15 0 0" size="0.15 0.1 0.01" mass="0.3"/>
    </body>
    <body name="ball" pos="-0.5 0 0.3"><freejoint/><geom name="ball" type="sphere" size="0.05"/></body>
    <body name="rod" pos="0 0.5 0.3">
      <freejoint/><geom name="rod" type="capsule" size="0.01 0.1"/>
      <geom name="tetra" type="mesh" mesh="tetra" pos="0 0 0.15"/>
    </body>
    <body name="block" mocap="true" pos="0 -0.5 0.1">
      <geom name="block" type="box" size="0.05 0.05 0.05"/>
    </body>
  </worldbody>
  <deformable>
)";
constexpr std::string_view kAfter = R"(
  </deformable>
</mujoco>
)";
constexpr int kSteps = 5;

std::filesystem::path SceneFile() {
  static const std::filesystem::path file = [] {
    const char* dir = std::getenv("TETCOSIM_FUZZ_DIR");
    const std::filesystem::path base =
        dir ? std::filesystem::path(dir)
            : std::filesystem::temp_directory_path() /
                  ("tetcosim_scene_fuzz_" + std::to_string(::getpid()));
    std::filesystem::create_directories(base / "scenes");
    return base / "scenes" / "fuzz.xml";
  }();
  return file;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::filesystem::path path = SceneFile();
  {
    std::ofstream file(path, std::ios::binary | std::ios::trunc);
    file << kBefore;
    file.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
    file << kAfter;
  }
  tetcosim::WorldOptions options;
  options.memory_limit = 32e6;  // (a few ten thousand tetrahedra: quick steps)
  try {
    std::unique_ptr<tetcosim::World> world = tetcosim::World::Load(path.string(), options);
    tetcosim::RolloutMetrics metrics(*world);
    for (int step = 0; step < kSteps; ++step) {
      world->Step();
      if (world->metrics().status != tetcosim::StepStatus::kOk) break;
      metrics.Observe(*world);
    }
    metrics.Summarize(*world);
  } catch (const tetcosim::Error&) {
  }
  return 0;
}
