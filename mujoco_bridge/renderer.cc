#include "mujoco_bridge/renderer.h"

#include <GL/osmesa.h>
#include <mujoco/mujoco.h>
#include <png.h>

#include <cstdio>
#include <filesystem>

#include "mesh/error.h"
#include "mujoco_bridge/model_names.h"
#include "mujoco_bridge/mujoco_errors.h"

namespace tetcosim {

struct Renderer::State {
  OSMesaContext context = nullptr;
  std::vector<unsigned char> buffer;  // OSMesa's RGBA colour buffer
  mjvScene scene;
  mjvCamera camera;
  mjvOption option;
  mjrContext render;
  bool scene_made = false;
  bool render_made = false;

  // releases whatever was made, also when the constructor throws half way
  ~State() {
    if (render_made) mjr_freeContext(&render);
    if (scene_made) mjv_freeScene(&scene);
    if (context) {
      OSMesaMakeCurrent(nullptr, nullptr, 0, 0, 0);
      OSMesaDestroyContext(context);
    }
  }
};

Renderer::Renderer(World& world, int width, int height, const std::string& camera)
    : world_(world), width_(width), height_(height), state_(std::make_unique<State>()) {
  if (width < 16 || height < 16 || width > 8192 || height > 8192) {
    throw Error("render size " + std::to_string(width) + " x " + std::to_string(height) +
                " is outside 16..8192");
  }
  mjModel* m = world.mutable_mj_model();
  const int camera_id = camera.empty() ? -1 : mj_name2id(m, mjOBJ_CAMERA, camera.c_str());
  if (!camera.empty() && camera_id < 0) {
    throw Error("no camera named '" + camera + "' in " + world.scene().path + "; the scene has " +
                NamesOf(m, mjOBJ_CAMERA) + " (leave the camera out for the free view)");
  }
  // the offscreen buffer must hold the image
  m->vis.global.offwidth = std::max(m->vis.global.offwidth, width);
  m->vis.global.offheight = std::max(m->vis.global.offheight, height);
  state_->context = OSMesaCreateContextExt(OSMESA_RGBA, 24, 8, 0, nullptr);
  if (!state_->context) throw Error("OSMesa could not create a context (is libosmesa6 installed?)");
  state_->buffer.resize(static_cast<size_t>(m->vis.global.offwidth) * m->vis.global.offheight * 4);
  if (!OSMesaMakeCurrent(state_->context, state_->buffer.data(), GL_UNSIGNED_BYTE,
                         m->vis.global.offwidth, m->vis.global.offheight)) {
    OSMesaDestroyContext(state_->context);
    throw Error("OSMesa could not make its context current");
  }
  // (freed by ~State also when made only in part: MuJoCo frees what is there)
  mjv_defaultScene(&state_->scene);
  mjr_defaultContext(&state_->render);
  state_->scene_made = true;
  state_->render_made = true;
  mjv_defaultOption(&state_->option);
  state_->option.flags[mjVIS_SKIN] = 1;
  try {
    CallMuJoCo([&] {
      mjv_makeScene(m, &state_->scene, 10000);
      mjr_makeContext(m, &state_->render, mjFONTSCALE_100);
      mjr_setBuffer(mjFB_OFFSCREEN, &state_->render);
    });
  } catch (const MuJoCoError& e) {
    throw Error(std::string("MuJoCo could not make its offscreen renderer: ") + e.what());
  }
  mjv_defaultCamera(&state_->camera);
  if (camera.empty()) {
    mjv_defaultFreeCamera(m, &state_->camera);
  } else {
    state_->camera.type = mjCAMERA_FIXED;
    state_->camera.fixedcamid = camera_id;
  }
  rgb_.resize(static_cast<size_t>(width) * height * 3);
}

Renderer::~Renderer() = default;

const std::vector<unsigned char>& Renderer::Render() {
  mjModel* m = world_.mutable_mj_model();
  mjData* d = world_.mj_data();
  mjvScene& scene = state_->scene;
  State& state = *state_;
  CallMuJoCo(
      [&] { mjv_updateScene(m, d, &state.option, nullptr, &state.camera, mjCAT_ALL, &scene); });
  // the deformables' current surfaces into their skins (skin i is tetbody i)
  for (int i = 0; i < world_.num_deformables() && i < scene.nskin; ++i) {
    const DeformableBody& body = world_.deformable(i);
    const TetMesh& mesh = body.mesh();
    Positions normals;
    ComputeVertexNormals(body.positions(), mesh.surface(), normals);
    const std::vector<int>& surface_vertices = mesh.surface_vertices();
    float* vertices = scene.skinvert + 3 * scene.skinvertadr[i];
    float* skin_normals = scene.skinnormal + 3 * scene.skinvertadr[i];
    for (size_t k = 0; k < surface_vertices.size() && static_cast<int>(k) < scene.skinvertnum[i];
         ++k) {
      for (int c = 0; c < 3; ++c) {
        vertices[3 * k + c] = static_cast<float>(body.positions()(surface_vertices[k], c));
        skin_normals[3 * k + c] = static_cast<float>(normals(surface_vertices[k], c));
      }
    }
  }
  mjrRect viewport = {0, 0, width_, height_};
  std::vector<unsigned char> flipped(rgb_.size());
  unsigned char* pixels = flipped.data();
  CallMuJoCo([&] {
    mjr_render(viewport, &scene, &state.render);
    mjr_readPixels(pixels, nullptr, viewport, &state.render);
  });
  // OpenGL's first row is the bottom one
  const size_t row = static_cast<size_t>(width_) * 3;
  for (int y = 0; y < height_; ++y) {
    std::copy(flipped.begin() + static_cast<long>(row * static_cast<size_t>(height_ - 1 - y)),
              flipped.begin() + static_cast<long>(row * static_cast<size_t>(height_ - y)),
              rgb_.begin() + static_cast<long>(row * static_cast<size_t>(y)));
  }
  return rgb_;
}

void WritePng(const std::string& path, const std::vector<unsigned char>& rgb, int width,
              int height) {
  const std::string temporary = path + ".tmp";
  FILE* file = std::fopen(temporary.c_str(), "wb");
  if (!file) throw Error(path + ": cannot write the image");
  png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, nullptr, nullptr, nullptr);
  png_infop info = png ? png_create_info_struct(png) : nullptr;
  if (!png || !info || setjmp(png_jmpbuf(png))) {
    png_destroy_write_struct(&png, &info);
    std::fclose(file);
    throw Error(path + ": PNG encoding failed");
  }
  png_init_io(png, file);
  png_set_IHDR(png, info, static_cast<png_uint_32>(width), static_cast<png_uint_32>(height), 8,
               PNG_COLOR_TYPE_RGB, PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT,
               PNG_FILTER_TYPE_DEFAULT);
  png_write_info(png, info);
  for (int y = 0; y < height; ++y) {
    png_write_row(png, const_cast<png_bytep>(rgb.data() + static_cast<size_t>(y) * width * 3));
  }
  png_write_end(png, nullptr);
  png_destroy_write_struct(&png, &info);
  if (std::fclose(file) != 0) throw Error(path + ": write failed");
  std::filesystem::rename(temporary, path);
}

}  // namespace tetcosim
