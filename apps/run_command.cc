// tetcosim run SCENE.xml: a headless rollout that writes summary.json,
// steps.csv, bodies.csv and (with --vtk) vtk/*.vtu with a series.pvd. Ctrl-C
// (or SIGTERM, SIGHUP) stops cleanly with everything written so far valid; a
// non-finite state stops the run with status "diverged", and a fatal error
// MuJoCo raised in a step with status "failed".

#include <unistd.h>

#include <atomic>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>

#include "apps/cli_checks.h"
#include "apps/commands.h"
#include "apps/csv.h"
#include "apps/interrupt.h"
#include "apps/json_text.h"
#include "apps/metrics_json.h"
#include "mesh/error.h"
#include "mesh/mesh_io.h"
#include "mesh/xml_text.h"
#include "mujoco_bridge/renderer.h"
#include "mujoco_bridge/rollout_metrics.h"
#include "mujoco_bridge/world.h"

namespace tetcosim::app {
namespace {

struct RunOptions {
  std::string scene;
  double duration = 0.0;
  long steps = 0;
  std::string method;
  std::string out = "out";
  double fps = 30.0;
  bool vtk = false;
  bool render = false;
  bool video = false;
  int width = 640;
  int height = 480;
  std::string camera;
  int threads = 1;
  double timestep = 0.0;
};

void WriteVtkFrame(const World& world, const std::filesystem::path& directory, int frame,
                   std::vector<std::pair<double, std::string>>& series) {
  for (int i = 0; i < world.num_deformables(); ++i) {
    const DeformableBody& body = world.deformable(i);
    std::string name = body.name() + "_" + std::to_string(frame) + ".vtu";
    VtkData data;
    const Positions& v = body.velocities();
    data.point_data.push_back({"velocity", 3, std::vector<double>(v.data(), v.data() + v.size())});
    WriteVtk((directory / name).string(), body.positions(), body.mesh().tets(), data);
    series.emplace_back(world.time(), name);
  }
  // the .pvd index, rewritten every frame so that it is always complete
  std::string pvd =
      "<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\">\n<Collection>\n";
  for (size_t k = 0; k < series.size(); ++k) {
    int part = static_cast<int>(k % static_cast<size_t>(std::max(1, world.num_deformables())));
    pvd += "<DataSet timestep=\"" + std::to_string(series[k].first) + "\" part=\"" +
           std::to_string(part) + "\" file=\"" + XmlEscaped(series[k].second) + "\"/>\n";
  }
  pvd += "</Collection>\n</VTKFile>\n";
  WriteFileAtomically((directory / "series.pvd").string(), pvd);
}

void RunRollout(const RunOptions& options) {
  WorldOptions world_options;
  if (options.method == "consistent") world_options.method = DepthMethod::kConsistent;
  if (options.method == "closest") world_options.method = DepthMethod::kClosest;
  world_options.threads = options.threads;
  if (options.timestep > 0.0) world_options.timestep = options.timestep;
  std::unique_ptr<World> world = World::Load(options.scene, world_options);
  PrintLoadWarnings(*world);
  for (const World::MadeProxy& made : world->made_proxies()) {
    std::fprintf(stderr, "tetcosim: note: geom %s is given a proxy (%s; <contact autoproxy>)\n",
                 made.geom.c_str(), made.why.c_str());
  }
  RolloutMetrics rollout_metrics(*world);
  const double dt = world->timestep();
  const long steps = options.steps > 0        ? options.steps
                     : options.duration > 0.0 ? StepCount(options.duration, dt, "--duration")
                                              : StepCount(1.0, dt, "the default duration");
  std::filesystem::path out(options.out);
  std::error_code error;
  std::filesystem::create_directories(out, error);
  if (error) throw Error(options.out + ": cannot create the output folder: " + error.message());
  if (options.vtk) std::filesystem::create_directories(out / "vtk");
  std::unique_ptr<Renderer> renderer;
  if (options.render || options.video) {
    std::filesystem::create_directories(out / "frames");
    renderer = std::make_unique<Renderer>(*world, options.width, options.height, options.camera);
  }

  std::ofstream steps_csv(out / "steps.csv");
  std::ofstream bodies_csv(out / "bodies.csv");
  std::ofstream deformables_csv(out / "deformables.csv");
  if (!steps_csv || !bodies_csv || !deformables_csv) {
    throw Error(options.out + ": cannot write the output files");
  }
  steps_csv << "step,time,colliding_points,max_depth,mean_depth,kinetic_deformable,kinetic_rigid,"
               "px,py,pz,direction_change_max_deg,neighbour_angle_mean_deg,fallback_points,"
               "unresolved_points,solver_iterations,contact_rounds,released_contacts,"
               "stuck_contacts,wall_ms\n";
  bodies_csv << "frame,time,body,x,y,z,qw,qx,qy,qz,vx,vy,vz,wx,wy,wz\n";
  deformables_csv << "frame,time,body,cx,cy,cz,vx,vy,vz,kinetic,xmin,ymin,zmin,xmax,ymax,zmax\n";
  // Frames: the initial state, then every frame_every steps, and the final
  // state (unless the run diverged). (A rate so low that not even one frame
  // falls in the run: the initial and the final state; the count of steps
  // between frames would not fit in a long.)
  const double steps_per_frame = std::round(1.0 / (options.fps * dt));
  const long frame_every = steps_per_frame < static_cast<double>(steps)
                               ? std::max(1L, static_cast<long>(steps_per_frame))
                               : steps;
  std::vector<std::pair<double, std::string>> series;

  CatchInterrupt();
  const bool terminal = isatty(fileno(stderr));
  std::string status = "ok";
  std::string message;
  double sum_ms[4] = {0, 0, 0, 0};  // collision, deformable, mujoco, total
  long sum_points = 0;
  double penetration_ms = 0.0;  // the penetration solver's part of sum_ms[0]
  long penetration_points = 0;
  long sum_iterations = 0;
  long sum_rounds = 0;
  long unconverged = 0;  // steps whose linear solve stopped short of the tolerance
  double max_residual = 0.0;
  int max_points = 0;
  double max_depth = 0.0;
  long done = 0;
  int frame = 0;
  long framed = -1;  // the steps done at the last frame
  char line[512];
  auto write_frame = [&] {
    for (int b = 1; b < world->num_rigid_bodies(); ++b) {
      Eigen::Vector3d x = world->RigidBodyPosition(b);
      Eigen::Quaterniond q = world->RigidBodyOrientation(b);
      Eigen::Vector3d v = world->RigidBodyLinearVelocity(b);
      Eigen::Vector3d w = world->RigidBodyAngularVelocity(b);
      // (the name on its own: a long one would not fit the line)
      std::snprintf(line, sizeof(line), "%d,%.9g,", frame, world->time());
      bodies_csv << line << CsvField(world->RigidBodyName(b));
      std::snprintf(line, sizeof(line),
                    ",%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g\n", x.x(),
                    x.y(), x.z(), q.w(), q.x(), q.y(), q.z(), v.x(), v.y(), v.z(), w.x(), w.y(),
                    w.z());
      bodies_csv << line;
    }
    for (int i = 0; i < world->num_deformables(); ++i) {
      const DeformableBody& body = world->deformable(i);
      const Eigen::Vector3d c = body.CenterOfMass();
      const Eigen::Vector3d v = body.CenterOfMassVelocity();
      const Eigen::Vector3d low = body.positions().colwise().minCoeff().transpose();
      const Eigen::Vector3d high = body.positions().colwise().maxCoeff().transpose();
      std::snprintf(line, sizeof(line), "%d,%.9g,", frame, world->time());
      deformables_csv << line << CsvField(body.name());
      std::snprintf(line, sizeof(line),
                    ",%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g\n", c.x(),
                    c.y(), c.z(), v.x(), v.y(), v.z(), body.KineticEnergy(), low.x(), low.y(),
                    low.z(), high.x(), high.y(), high.z());
      deformables_csv << line;
    }
    if (options.vtk) WriteVtkFrame(*world, out / "vtk", frame, series);
    if (renderer) {
      char name[32];
      std::snprintf(name, sizeof(name), "%05d.png", frame);
      WritePng((out / "frames" / name).string(), renderer->Render(), renderer->width(),
               renderer->height());
    }
    ++frame;
    framed = done;
    steps_csv.flush();
    bodies_csv.flush();
    deformables_csv.flush();
  };
  write_frame();
  auto start = std::chrono::steady_clock::now();
  for (long step = 0; step < steps; ++step) {
    if (interrupted) {
      status = "interrupted";
      break;
    }
    world->Step();
    const StepMetrics& metrics = world->metrics();
    if (metrics.status != StepStatus::kOk) {
      status = StoppedStatusName(metrics.status);
      message = metrics.message;
      break;
    }
    ++done;
    rollout_metrics.Observe(*world);
    sum_ms[0] += metrics.collision_ms;
    sum_ms[1] += metrics.deformable_ms;
    sum_ms[2] += metrics.mujoco_ms;
    sum_ms[3] += metrics.total_ms;
    sum_points += metrics.colliding_points;
    penetration_ms += metrics.penetration_ms;
    penetration_points += metrics.penetration_points;
    sum_iterations += metrics.solver_iterations;
    sum_rounds += metrics.contact_rounds;
    max_points = std::max(max_points, metrics.colliding_points);
    if (!metrics.solver_converged) ++unconverged;
    max_residual = std::max(max_residual, metrics.solver_residual);
    max_depth = std::max(max_depth, metrics.max_depth);
    Eigen::Vector3d p = world->LinearMomentum();
    std::snprintf(
        line, sizeof(line),
        "%ld,%.9g,%d,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.6g,%.6g,%d,%d,%d,%d,%d,%d,%.6g\n",
        step + 1, world->time(), metrics.colliding_points, metrics.max_depth, metrics.mean_depth,
        world->DeformableKineticEnergy(), world->RigidKineticEnergy(), p.x(), p.y(), p.z(),
        rollout_metrics.step_max_direction_change(), rollout_metrics.step_mean_neighbour_angle(),
        metrics.fallback_points, metrics.unresolved_points, metrics.solver_iterations,
        metrics.contact_rounds, metrics.released_contacts, metrics.stuck_contacts,
        metrics.total_ms);
    steps_csv << line;
    if (done % frame_every == 0) write_frame();
    if (terminal && (step % 50 == 0 || step + 1 == steps)) {
      std::fprintf(stderr, "\r[%3d%%] step %ld / %ld, t = %.3f s",
                   static_cast<int>(100 * (step + 1) / steps), step + 1, steps, world->time());
    }
  }
  if (terminal) std::fprintf(stderr, "\n");
  // the final state, unless it is a frame already (World::Step undoes a
  // step it cannot complete: the state is the last step done's)
  if (framed != done) write_frame();
  const bool stopped = status == "diverged" || status == "failed";
  steps_csv.close();
  bodies_csv.close();
  deformables_csv.close();
  const double wall =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

  nlohmann::ordered_json summary;
  summary["status"] = status;
  if (!message.empty()) summary["message"] = message;
  summary["scene"] = options.scene;
  long vertices = 0, tets = 0;
  for (int i = 0; i < world->num_deformables(); ++i) {
    vertices += world->deformable(i).num_vertices();
    tets += world->deformable(i).mesh().num_tets();
  }
  summary["counts"] = {{"deformables", world->num_deformables()},
                       {"vertices", vertices},
                       {"tetrahedra", tets},
                       {"rigid_bodies", world->num_rigid_bodies() - 1},
                       {"proxies", world->num_proxies()}};
  summary["steps"] = done;
  summary["sim_time"] = world->time();
  summary["wall_time"] = wall;
  summary["dt"] = dt;
  summary["steps_per_second"] = wall > 0.0 ? static_cast<double>(done) / wall : 0.0;
  const double n = std::max<double>(1.0, static_cast<double>(done));
  summary["ms_per_step"] = {{"collision", sum_ms[0] / n},
                            {"deformable", sum_ms[1] / n},
                            {"mujoco", sum_ms[2] / n},
                            {"total", sum_ms[3] / n}};
  summary["mean_solver_iterations"] = static_cast<double>(sum_iterations) / n;
  summary["mean_contact_rounds"] = static_cast<double>(sum_rounds) / n;
  summary["unconverged_steps"] = unconverged;
  summary["max_solver_residual"] = max_residual;
  summary["contacts"] = {
      {"max_colliding_points", max_points},
      {"mean_colliding_points", static_cast<double>(sum_points) / n},
      {"us_per_colliding_point",
       sum_points > 0 ? sum_ms[0] * 1e3 / static_cast<double>(sum_points) : 0.0},
      // the penetration solver alone (its points: no geom contacts)
      {"penetration_ms_per_step", penetration_ms / n},
      {"penetration_us_per_point",
       penetration_points > 0 ? penetration_ms * 1e3 / static_cast<double>(penetration_points)
                              : 0.0},
      {"max_depth", max_depth},
      {"final_max_depth", world->metrics().max_depth}};
  summary["final_kinetic_energy"] = {{"deformable", world->DeformableKineticEnergy()},
                                     {"rigid", world->RigidKineticEnergy()}};
  const RolloutSummary rollout = rollout_metrics.Summarize(*world);
  summary["metrics"] = MetricsJson(rollout, rollout_metrics.options());
  const std::vector<World::MuJoCoWarning> warnings = world->MuJoCoWarnings();
  summary["mujoco_warnings"] = MuJoCoWarningsJson(warnings);
  WriteFileAtomically((out / "summary.json").string(), JsonText(summary) + "\n");
  std::printf("%s: %ld steps, %.3f s simulated in %.2f s wall (%.0f steps/s): %s\n",
              options.scene.c_str(), done, world->time(), wall,
              static_cast<double>(done) / std::max(wall, 1e-9), status.c_str());
  std::printf(
      "  ms per step: collision %.3f (penetration solver %.3f), deformable %.3f, mujoco %.3f, "
      "total %.3f\n",
      sum_ms[0] / n, penetration_ms / n, sum_ms[1] / n, sum_ms[2] / n, sum_ms[3] / n);
  std::printf(
      "  pass-through pairs %d, sticking pairs %d, residual depth max %.3g m, mean %.3g m, "
      "final kinetic energy %.3g J%s\n",
      rollout.pass_through_pairs, rollout.sticking_pairs, rollout.residual_max_depth,
      rollout.residual_mean_depth, rollout.final_kinetic_energy,
      rollout.at_rest ? " (at rest)" : "");
  if (unconverged > 0) {
    std::printf(
        "  the linear solve stopped short of its tolerance in %ld of %ld steps (largest "
        "residual %.3g, tolerance %g): those steps are inexact; raise <solver maxiter> (%d), or "
        "look for extreme materials\n",
        unconverged, done, max_residual, world->scene().solver.tolerance,
        world->scene().solver.max_iterations);
  }
  for (const World::MuJoCoWarning& warning : warnings) {
    std::printf("  MuJoCo warned %d time%s: %s\n", warning.count, warning.count == 1 ? "" : "s",
                warning.what.c_str());
  }
  std::printf("  wrote %s/summary.json, steps.csv, bodies.csv, deformables.csv%s\n",
              options.out.c_str(), options.vtk ? ", vtk/" : "");
  if (options.video && frame > 0) {
    if (std::system("command -v ffmpeg > /dev/null 2>&1") != 0) {
      std::fprintf(
          stderr,
          "tetcosim: no video: ffmpeg is not installed (scripts/install-deps installs it); "
          "the frames are in %s/frames\n",
          options.out.c_str());
    } else {
      // frames at the rollout's frame rate; even sizes for yuv420p
      std::string command =
          "ffmpeg -loglevel error -y -framerate " + std::to_string(1.0 / (frame_every * dt)) +
          " -i '" + (out / "frames" / "%05d.png").string() +
          "' -vf 'pad=ceil(iw/2)*2:ceil(ih/2)*2' -pix_fmt yuv420p -c:v libx264 '" +
          (out / "video.mp4").string() + "'";
      if (std::system(command.c_str()) != 0) {
        std::fprintf(stderr, "tetcosim: ffmpeg failed; the frames are in %s/frames\n",
                     options.out.c_str());
      } else {
        std::printf("  wrote %s/video.mp4 (%d frames)\n", options.out.c_str(), frame);
      }
    }
  }
  if (stopped) throw Error(message);
  if (status == "interrupted") throw Error("interrupted; the outputs written so far are complete");
}

}  // namespace

void AddRunCommand(CLI::App& app) {
  auto options = std::make_shared<RunOptions>();
  CLI::App* run = app.add_subcommand("run", "Run a scene headless and write its data");
  run->add_option("scene", options->scene, "Scene file (MJCF with a <deformable> element)")
      ->required();
  auto* duration = run->add_option("--duration", options->duration, "Simulated seconds (default 1)")
                       ->check(PositiveFiniteNumber());
  run->add_option("--steps", options->steps, "Number of steps")
      ->check(StepNumber())
      ->excludes(duration);
  run->add_option("--method", options->method, "consistent or closest (default: the scene's)")
      ->check(CLI::IsMember({"consistent", "closest"}));
  run->add_option("--out", options->out, "Output folder (default out)");
  run->add_option("--fps", options->fps,
                  "Frames per second for bodies.csv, deformables.csv, VTK and PNG (default 30)")
      ->check(PositiveFiniteNumber());
  run->add_flag("--vtk", options->vtk,
                "Write the deformable meshes per frame (vtk/*.vtu, series.pvd)");
  run->add_flag("--render", options->render, "Render frames offscreen (frames/NNNNN.png)");
  run->add_flag("--video", options->video, "Render frames and make video.mp4 with ffmpeg");
  run->add_option("--width", options->width, "Image width (default 640)")
      ->check(CLI::Range(16, 8192));
  run->add_option("--height", options->height, "Image height (default 480)")
      ->check(CLI::Range(16, 8192));
  run->add_option("--camera", options->camera, "A camera of the scene (default: a free camera)");
  run->add_option("--threads", options->threads, "Threads (default 1)")->check(CLI::Range(1, 256));
  run->add_option("--timestep", options->timestep, "Override the scene's timestep (s)")
      ->check(PositiveFiniteNumber());
  run->callback([options] { RunRollout(*options); });
}

}  // namespace tetcosim::app
