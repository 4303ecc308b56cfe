#pragma once

// Offscreen rendering of a World with OSMesa (no window system, no EGL: with
// libEGL in the process MuJoCo 2.2.2's GL loader picks EGL and fails).
// Deformables are drawn as lit surfaces through the MJCF <skin> the World
// injects for each of them (one bone on the world body): after
// mjv_updateScene the renderer overwrites the scene's skin vertices and
// normals with the current surface.

#include <memory>
#include <string>
#include <vector>

#include "mujoco_bridge/world.h"

namespace tetcosim {

class Renderer {
 public:
  // camera: a camera name of the model, or empty for a free camera that
  // frames the whole scene. Throws Error if OSMesa or MuJoCo's renderer
  // cannot be set up or the camera does not exist.
  Renderer(World& world, int width, int height, const std::string& camera = "");
  ~Renderer();
  Renderer(const Renderer&) = delete;
  Renderer& operator=(const Renderer&) = delete;

  int width() const { return width_; }
  int height() const { return height_; }
  // Renders the world's current state: width x height RGB, top row first.
  // Throws MuJoCoError (mujoco_errors.h) if MuJoCo raises a fatal error.
  const std::vector<unsigned char>& Render();

 private:
  struct State;
  World& world_;
  int width_;
  int height_;
  std::unique_ptr<State> state_;
  std::vector<unsigned char> rgb_;
};

// Writes an RGB image (top row first) as PNG. Throws Error on failure.
void WritePng(const std::string& path, const std::vector<unsigned char>& rgb, int width,
              int height);

}  // namespace tetcosim
