// tetcosim compare SCENE.xml: the scene run with both depth methods over a
// list of time steps, side by side (issue 6). Writes into DIR:
//   runs/<method>-<dt>ms/{summary.json, steps.csv, frame.png}
//   table.csv, table.md   metrics per run, rewritten after every run
//   depth.png, energy.png plots over time (gnuplot; plots.gp is kept)
// A run is plausible when it stays finite and has no pass-through and no
// sticking pair (RolloutMetrics).

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "apps/cli_checks.h"
#include "apps/commands.h"
#include "apps/interrupt.h"
#include "apps/json_text.h"
#include "apps/metrics_json.h"
#include "mesh/error.h"
#include "mesh/mesh_io.h"
#include "mujoco_bridge/renderer.h"
#include "mujoco_bridge/rollout_metrics.h"
#include "mujoco_bridge/world.h"

namespace tetcosim::app {
namespace {

struct CompareOptions {
  std::string scene;
  std::vector<std::string> dt = {"0.5", "1", "2", "4", "8"};
  std::vector<std::string> methods = {"consistent", "closest"};
  double duration = 1.0;
  std::string out;
  int threads = 1;
  int width = 480;
  int height = 360;
  std::string camera;
  bool render = true;
};

struct RunRow {
  std::string method;
  double dt_ms = 0.0;
  std::string status;
  double steps_per_second = 0.0;
  RolloutSummary summary;
  bool plausible = false;
  std::string folder;  // relative to the output folder
};

// "0.5", "2ms" -> milliseconds; "0.004s" -> 4
double ParseMilliseconds(const std::string& text) {
  std::string number = text;
  double scale = 1.0;
  if (number.size() > 2 && number.compare(number.size() - 2, 2, "ms") == 0) {
    number.resize(number.size() - 2);
  } else if (number.size() > 1 && number.back() == 's') {
    number.pop_back();
    scale = 1e3;
  }
  size_t used = 0;
  double value = 0.0;
  try {
    value = std::stod(number, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used != number.size() || !(value > 0.0) || !std::isfinite(value)) {
    throw Error("--dt: '" + text +
                "' is not a positive time step (milliseconds, e.g. 0.5,1,2 or 2ms or 0.002s)");
  }
  return value * scale;
}

std::string Format(const char* format, double value) {
  char text[64];
  std::snprintf(text, sizeof(text), format, value);
  return text;
}

std::string RunName(const std::string& method, double dt_ms) {
  return method + "-" + Format("%g", dt_ms) + "ms";
}

RunRow RunOne(const CompareOptions& options, const std::string& method, double dt_ms,
              const std::filesystem::path& out, bool is_first_run) {
  RunRow row;
  row.method = method;
  row.dt_ms = dt_ms;
  row.folder = "runs/" + RunName(method, dt_ms);

  WorldOptions world_options;
  world_options.method = method == "closest" ? DepthMethod::kClosest : DepthMethod::kConsistent;
  world_options.threads = options.threads;
  world_options.timestep = dt_ms * 1e-3;
  // a bad scene is reported here, at the first run, before it writes anything
  std::unique_ptr<World> world = World::Load(options.scene, world_options);
  if (is_first_run) PrintLoadWarnings(*world);  // (the same for every run)
  // (told once per time step: at its first method)
  const long steps = StepCount(options.duration, world->timestep(), "--duration",
                               /*warn=*/method == options.methods.front());
  const std::filesystem::path folder = out / row.folder;
  std::filesystem::create_directories(folder);
  RolloutMetrics metrics(*world);

  std::ofstream csv(folder / "steps.csv");
  if (!csv) throw Error(folder.string() + ": cannot write steps.csv");
  csv << "step,time,colliding_points,max_depth,mean_depth,kinetic_energy,"
         "direction_change_max_deg,neighbour_angle_mean_deg\n";
  row.status = "ok";
  std::string message;
  auto start = std::chrono::steady_clock::now();
  long done = 0;
  long unconverged = 0;  // steps whose linear solve stopped short of the tolerance
  for (long step = 0; step < steps; ++step) {
    if (interrupted) {
      row.status = "interrupted";
      break;
    }
    world->Step();
    const StepMetrics& m = world->metrics();
    if (m.status != StepStatus::kOk) {
      row.status = StoppedStatusName(m.status);
      message = m.message;
      break;
    }
    ++done;
    if (!m.solver_converged) ++unconverged;
    metrics.Observe(*world);
    char line[256];
    std::snprintf(line, sizeof(line), "%ld,%.9g,%d,%.9g,%.9g,%.9g,%.6g,%.6g\n", step + 1,
                  world->time(), m.colliding_points, m.max_depth, m.mean_depth,
                  world->DeformableKineticEnergy() + world->RigidKineticEnergy(),
                  metrics.step_max_direction_change(), metrics.step_mean_neighbour_angle());
    csv << line;
  }
  csv.close();
  const double wall =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  row.steps_per_second = wall > 0.0 ? static_cast<double>(done) / wall : 0.0;
  row.summary = metrics.Summarize(*world);
  const std::vector<World::MuJoCoWarning> warnings = world->MuJoCoWarnings();
  const bool dropped = std::any_of(warnings.begin(), warnings.end(),
                                   [](const World::MuJoCoWarning& w) { return w.dropped; });
  row.plausible = row.status == "ok" && row.summary.pass_through_pairs == 0 &&
                  row.summary.sticking_pairs == 0 &&
                  std::isfinite(row.summary.final_kinetic_energy) && unconverged == 0 && !dropped;

  nlohmann::ordered_json summary;
  summary["scene"] = options.scene;
  summary["method"] = method;
  summary["dt"] = world->timestep();
  summary["status"] = row.status;
  if (!message.empty()) summary["message"] = message;
  summary["steps"] = done;
  summary["sim_time"] = world->time();
  summary["steps_per_second"] = row.steps_per_second;
  summary["plausible"] = row.plausible;
  summary["metrics"] = MetricsJson(row.summary, metrics.options());
  summary["unconverged_steps"] = unconverged;
  summary["mujoco_warnings"] = MuJoCoWarningsJson(warnings);
  WriteFileAtomically((folder / "summary.json").string(), JsonText(summary) + "\n");
  if (options.render && row.status != "interrupted") {
    Renderer renderer(*world, options.width, options.height, options.camera);
    WritePng((folder / "frame.png").string(), renderer.Render(), options.width, options.height);
  }
  std::printf(
      "  %-10s dt %5g ms: %-8s pass-through %d, sticking %d, residual max %.3g mm, "
      "KE %.3g J, %s (%.0f steps/s)\n",
      method.c_str(), dt_ms, row.status.c_str(), row.summary.pass_through_pairs,
      row.summary.sticking_pairs, row.summary.residual_max_depth * 1e3,
      row.summary.final_kinetic_energy, row.plausible ? "plausible" : "NOT plausible",
      row.steps_per_second);
  std::fflush(stdout);
  return row;
}

// "0.5-4 ms" for the plausible time steps of one method ("none" if none);
// gaps are listed
std::string PlausibleRange(const std::vector<RunRow>& rows, const std::string& method) {
  std::vector<double> ok;
  for (const RunRow& row : rows) {
    if (row.method == method && row.plausible) ok.push_back(row.dt_ms);
  }
  if (ok.empty()) return "none";
  std::vector<double> all;
  for (const RunRow& row : rows) {
    if (row.method == method) all.push_back(row.dt_ms);
  }
  if (ok.size() == all.size()) {
    return Format("%g", ok.front()) + "-" + Format("%g", ok.back()) + " ms (all)";
  }
  std::string text;
  for (double dt : ok) text += (text.empty() ? "" : ", ") + Format("%g", dt);
  return text + " ms";
}

void WriteTables(const CompareOptions& options, const std::vector<RunRow>& rows,
                 const std::filesystem::path& out) {
  std::ostringstream csv;
  csv << "method,dt_ms,status,plausible,pass_through_pairs,sticking_pairs,residual_max_depth_mm,"
         "residual_mean_depth_mm,max_depth_seen_mm,mean_neighbour_angle_deg,"
         "max_direction_change_deg,mean_direction_change_deg,fallback_points,unresolved_points,"
         "final_kinetic_energy_J,at_rest,us_per_colliding_point,steps_per_second\n";
  std::ostringstream md;
  md << "Scene `" << options.scene << "`, " << options.duration
     << " s simulated per run. Depths in mm, angles in degrees.\n\n"
     << "| method | dt (ms) | plausible | pass-through | sticking | residual max | residual mean "
        "| max depth seen | neighbour angle | max dir. change | mean dir. change | fallback | "
        "no value | final KE (J) | at rest | us/point | steps/s |\n"
     << "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|\n";
  for (const RunRow& r : rows) {
    const RolloutSummary& s = r.summary;
    char line[1024];
    std::snprintf(line, sizeof(line),
                  "%s,%g,%s,%d,%d,%d,%.4g,%.4g,%.4g,%.4g,%.4g,%.4g,%ld,%ld,%.4g,%d,%.4g,%.4g\n",
                  r.method.c_str(), r.dt_ms, r.status.c_str(), r.plausible ? 1 : 0,
                  s.pass_through_pairs, s.sticking_pairs, s.residual_max_depth * 1e3,
                  s.residual_mean_depth * 1e3, s.max_depth_seen * 1e3, s.mean_neighbour_angle,
                  s.max_direction_change, s.mean_direction_change, s.fallback_points,
                  s.unresolved_points, s.final_kinetic_energy, s.at_rest ? 1 : 0,
                  s.collision_us_per_point, r.steps_per_second);
    csv << line;
    std::snprintf(
        line, sizeof(line),
        "| %s | %g | %s | %d | %d | %.3g | %.3g | %.3g | %.1f | %.1f | %.2f | %ld | %ld | "
        "%.3g | %s | %.2f | %.0f |\n",
        r.method.c_str(), r.dt_ms,
        r.status != "ok" ? r.status.c_str() : (r.plausible ? "yes" : "**no**"),
        s.pass_through_pairs, s.sticking_pairs, s.residual_max_depth * 1e3,
        s.residual_mean_depth * 1e3, s.max_depth_seen * 1e3, s.mean_neighbour_angle,
        s.max_direction_change, s.mean_direction_change, s.fallback_points, s.unresolved_points,
        s.final_kinetic_energy, s.at_rest ? "yes" : "no", s.collision_us_per_point,
        r.steps_per_second);
    md << line;
  }
  md << "\nPlausible time steps:";
  for (const std::string& method : options.methods) {
    md << " " << method << " " << PlausibleRange(rows, method) << ";";
  }
  md.seekp(-1, std::ios_base::cur);
  md << ".\n";
  WriteFileAtomically((out / "table.csv").string(), csv.str());
  WriteFileAtomically((out / "table.md").string(), md.str());
}

// depth.png and energy.png over time, one curve per run, with gnuplot
void WritePlots(const std::vector<RunRow>& rows, const std::filesystem::path& out) {
  std::ostringstream gp;
  gp << "# made by tetcosim compare; run: gnuplot plots.gp\n"
        "set datafile separator ','\nset terminal pngcairo size 900,420 noenhanced\n"
        "set key outside right\nset xlabel 'time (s)'\nset grid\nset format y '%g'\n";
  // one colour per time step; consistent solid, closest dashed
  std::vector<double> dts;
  for (const RunRow& row : rows) {
    if (std::find(dts.begin(), dts.end(), row.dt_ms) == dts.end()) dts.push_back(row.dt_ms);
  }
  auto curves = [&](const char* column) {
    std::string text;
    for (size_t k = 0; k < rows.size(); ++k) {
      const long colour = std::find(dts.begin(), dts.end(), rows[k].dt_ms) - dts.begin() + 1;
      text += (k == 0 ? "plot " : ", ");
      text += "'" + rows[k].folder + "/steps.csv' using 2:(" + column + ") with lines lw 1.5 lc " +
              std::to_string(colour) + (rows[k].method == "closest" ? " dt 2 " : " dt 1 ") +
              "title '" + RunName(rows[k].method, rows[k].dt_ms) + "'";
    }
    return text + "\n";
  };
  gp << "set output 'depth.png'\nset ylabel 'max penetration depth (mm)'\n" << curves("$4*1000");
  gp << "set output 'energy.png'\nset ylabel 'kinetic energy (J)'\nset logscale y\n"
     << curves("$6 > 0 ? $6 : 1e-12");
  WriteFileAtomically((out / "plots.gp").string(), gp.str());
  if (std::system("command -v gnuplot > /dev/null 2>&1") != 0) {
    std::fprintf(stderr,
                 "tetcosim: no plots: gnuplot is not installed (scripts/install-deps --tools); "
                 "the script is %s/plots.gp\n",
                 out.string().c_str());
    return;
  }
  std::string command = "cd '" + out.string() + "' && gnuplot plots.gp";
  if (std::system(command.c_str()) != 0) {
    std::fprintf(stderr, "tetcosim: gnuplot failed on %s/plots.gp\n", out.string().c_str());
  }
}

void RunCompare(CompareOptions options) {
  std::vector<double> dts;
  for (const std::string& text : options.dt) {
    dts.push_back(ParseMilliseconds(text));
    // (a repeated step would run twice into the same folder and table row)
    if (std::count(dts.begin(), dts.end(), dts.back()) > 1) {
      throw Error("--dt: '" + text + "' repeats a time step given before it");
    }
  }
  for (const std::string& method : options.methods) {
    if (method != "consistent" && method != "closest") {
      throw Error("--methods: '" + method + "' is not consistent or closest");
    }
    if (std::count(options.methods.begin(), options.methods.end(), method) > 1) {
      throw Error("--methods: '" + method + "' is given twice");
    }
  }
  if (options.out.empty()) {
    options.out = "compare-" + std::filesystem::path(options.scene).stem().string();
  }
  const std::filesystem::path out(options.out);
  std::error_code error;
  std::filesystem::create_directories(out, error);
  if (error) throw Error(options.out + ": cannot create the output folder: " + error.message());

  CatchInterrupt();
  std::printf("%s: %zu runs of %g s into %s/\n", options.scene.c_str(),
              dts.size() * options.methods.size(), options.duration, options.out.c_str());
  std::vector<RunRow> rows;
  for (double dt : dts) {
    for (const std::string& method : options.methods) {
      rows.push_back(RunOne(options, method, dt, out, rows.empty()));
      WriteTables(options, rows, out);
      if (interrupted) break;
    }
    if (interrupted) break;
  }
  WritePlots(rows, out);
  for (const std::string& method : options.methods) {
    std::printf("  %s plausible at: %s\n", method.c_str(), PlausibleRange(rows, method).c_str());
  }
  std::printf("  wrote %s/table.md, table.csv, plots and runs/\n", options.out.c_str());
  if (interrupted) throw Error("interrupted; the runs finished so far are in the tables");
}

}  // namespace

void AddCompareCommand(CLI::App& app) {
  auto options = std::make_shared<CompareOptions>();
  CLI::App* compare = app.add_subcommand(
      "compare", "Run a scene with both depth methods over several time steps, side by side");
  compare->add_option("scene", options->scene, "Scene file (MJCF with a <deformable> element)")
      ->required();
  compare
      ->add_option("--dt", options->dt,
                   "Time steps in milliseconds, comma separated (default 0.5,1,2,4,8; "
                   "'2ms' and '0.002s' work too)")
      ->delimiter(',');
  compare->add_option("--methods", options->methods, "Depth methods (default consistent,closest)")
      ->delimiter(',');
  compare->add_option("--duration", options->duration, "Simulated seconds per run (default 1)")
      ->check(PositiveFiniteNumber());
  compare->add_option("--out", options->out, "Output folder (default compare-<scene name>)");
  compare->add_option("--threads", options->threads, "Threads (default 1)")
      ->check(CLI::Range(1, 256));
  compare->add_option("--width", options->width, "Picture width (default 480)")
      ->check(CLI::Range(16, 8192));
  compare->add_option("--height", options->height, "Picture height (default 360)")
      ->check(CLI::Range(16, 8192));
  compare->add_option("--camera", options->camera, "A camera of the scene (default: free camera)");
  compare->add_flag("!--no-render", options->render, "Do not render a picture per run");
  compare->callback([options] { RunCompare(*options); });
}

}  // namespace tetcosim::app
