// tetcosim info FILE [--json]: counts, size and element quality of a mesh.

#include <cstdio>
#include <nlohmann/json.hpp>

#include "apps/cli_checks.h"
#include "apps/commands.h"
#include "apps/json_text.h"
#include "mesh/mesh_io.h"
#include "mesh/quality.h"
#include "mujoco_bridge/world.h"

namespace tetcosim::app {
namespace {

struct InfoOptions {
  std::string file;
  bool json = false;
};

bool IsScene(const std::string& file) {
  return file.size() > 4 && file.compare(file.size() - 4, 4, ".xml") == 0;
}

// a scene: what it holds, after loading it completely (MuJoCo included)
void RunSceneInfo(const InfoOptions& options) {
  std::unique_ptr<World> world = World::Load(options.file);
  PrintLoadWarnings(*world);
  const SceneSpec& scene = world->scene();
  nlohmann::ordered_json out;
  out["scene"] = options.file;
  out["timestep"] = world->timestep();
  out["method"] = DepthMethodName(scene.method);
  const char* area = ContactAreaName(world->contact_area());
  out["contact_area"] = area;
  out["rigid_bodies"] = world->num_rigid_bodies() - 1;
  out["proxies"] = world->num_proxies();
  out["warnings"] = world->load_warnings();
  out["attachments"] = scene.attachments.size();
  const std::vector<World::GeomSummary> geoms = world->GeomsMetByShape();
  out["geoms_without_proxies"] = nlohmann::json::array();
  for (const World::GeomSummary& geom : geoms) {
    out["geoms_without_proxies"].push_back({{"name", geom.name}, {"shape", geom.shape}});
  }
  out["made_proxies"] = nlohmann::json::array();
  for (const World::MadeProxy& made : world->made_proxies()) {
    out["made_proxies"].push_back(
        {{"name", made.geom}, {"why", made.why}, {"tetrahedra", made.num_tets}});
  }
  out["deformables"] = nlohmann::json::array();
  for (int i = 0; i < world->num_deformables(); ++i) {
    const DeformableBody& body = world->deformable(i);
    out["deformables"].push_back({{"name", body.name()},
                                  {"vertices", body.num_vertices()},
                                  {"tetrahedra", body.mesh().num_tets()},
                                  {"mass", body.model().total_mass()},
                                  {"young", body.model().material().young},
                                  {"contact_stiffness", world->contact_pressure_stiffness(i)},
                                  {"pinned", body.pinned_vertices().size()}});
  }
  if (options.json) {
    std::printf("%s\n", JsonText(out).c_str());
    return;
  }
  std::printf("scene        %s\n", options.file.c_str());
  std::printf("timestep     %g s, method %s, contact area %s\n", world->timestep(),
              DepthMethodName(scene.method), area);
  std::printf("MuJoCo       %d bodies, %d with tetrahedral proxies\n",
              world->num_rigid_bodies() - 1, world->num_proxies());
  for (const World::GeomSummary& geom : geoms) {
    std::printf("geom         %s: %s, without a proxy\n", geom.name.c_str(), geom.shape.c_str());
  }
  for (const World::MadeProxy& made : world->made_proxies()) {
    std::printf("geom         %s: a proxy of %d tetrahedra made for it (%s)\n", made.geom.c_str(),
                made.num_tets, made.why.c_str());
  }
  for (int i = 0; i < world->num_deformables(); ++i) {
    const DeformableBody& body = world->deformable(i);
    std::printf(
        "tetbody      %s: %d vertices, %d tetrahedra, %.4g kg, E = %g Pa, contact stiffness %.4g "
        "Pa/m, %zu pinned\n",
        body.name().c_str(), body.num_vertices(), body.mesh().num_tets(), body.model().total_mass(),
        body.model().material().young, world->contact_pressure_stiffness(i),
        body.pinned_vertices().size());
  }
}

void RunInfo(const InfoOptions& options) {
  if (IsScene(options.file)) {
    RunSceneInfo(options);
    return;
  }
  TetMesh mesh = LoadMesh(options.file);
  PrintMeshWarnings(mesh);
  MeshQuality quality = ComputeQuality(mesh);
  Eigen::Vector3d lo = mesh.bbox_min();
  Eigen::Vector3d hi = mesh.bbox_max();
  if (options.json) {
    nlohmann::ordered_json out;
    out["file"] = mesh.source();
    out["vertices"] = mesh.num_vertices();
    out["tetrahedra"] = mesh.num_tets();
    out["surface_triangles"] = mesh.surface().rows();
    out["surface_vertices"] = mesh.surface_vertices().size();
    out["edges"] = mesh.edges().rows();
    out["volume"] = mesh.total_volume();
    out["bbox_min"] = {lo.x(), lo.y(), lo.z()};
    out["bbox_max"] = {hi.x(), hi.y(), hi.z()};
    out["average_edge_length"] = mesh.average_edge_length();
    out["flipped_tetrahedra"] = mesh.num_flipped();
    out["quality"] = {{"min_dihedral_deg", quality.min_dihedral_deg},
                      {"max_dihedral_deg", quality.max_dihedral_deg},
                      {"min_radius_ratio", quality.min_radius_ratio},
                      {"mean_radius_ratio", quality.mean_radius_ratio}};
    out["warnings"] = mesh.warnings();
    std::printf("%s\n", JsonText(out).c_str());
    return;
  }
  std::printf("file                 %s\n", mesh.source().c_str());
  std::printf("vertices             %d (%zu on the surface)\n", mesh.num_vertices(),
              mesh.surface_vertices().size());
  std::printf("tetrahedra           %d (%d flipped to positive volume)\n", mesh.num_tets(),
              mesh.num_flipped());
  std::printf("surface triangles    %ld\n", static_cast<long>(mesh.surface().rows()));
  std::printf("edges                %ld\n", static_cast<long>(mesh.edges().rows()));
  std::printf("volume               %.6g\n", mesh.total_volume());
  std::printf("bounding box         [%.6g, %.6g, %.6g] .. [%.6g, %.6g, %.6g]\n", lo.x(), lo.y(),
              lo.z(), hi.x(), hi.y(), hi.z());
  std::printf("average edge length  %.6g\n", mesh.average_edge_length());
  std::printf("dihedral angles      %.2f .. %.2f degrees\n", quality.min_dihedral_deg,
              quality.max_dihedral_deg);
  std::printf("radius ratio         min %.4f, mean %.4f (1 = regular)\n", quality.min_radius_ratio,
              quality.mean_radius_ratio);
}

}  // namespace

void AddCheckCommand(CLI::App& app) {
  auto file = std::make_shared<std::string>();
  CLI::App* check =
      app.add_subcommand("check", "Validate a scene (MJCF with <deformable>) without running it");
  check->add_option("scene", *file, "Scene file")->required();
  check->callback([file] {
    std::unique_ptr<World> world = World::Load(*file);
    PrintLoadWarnings(*world);
    std::printf("%s: ok (%d deformables, %d MuJoCo bodies)\n", file->c_str(),
                world->num_deformables(), world->num_rigid_bodies() - 1);
    for (const World::MadeProxy& made : world->made_proxies()) {
      std::printf("  geom %s: a proxy made for it (%s)\n", made.geom.c_str(), made.why.c_str());
    }
  });
}

void AddInfoCommand(CLI::App& app) {
  auto options = std::make_shared<InfoOptions>();
  CLI::App* info = app.add_subcommand(
      "info", "Summarise a tetrahedral mesh (counts, volume, bounds, quality) or a scene (.xml)");
  info->add_option("file", options->file,
                   "Mesh file (.msh, .node/.ele, .vtk, .vtu) or shape spec such as "
                   "sphere:size=0.1:res=1")
      ->required();
  info->add_flag("--json", options->json, "Print JSON instead of text");
  info->callback([options] { RunInfo(*options); });
}

}  // namespace tetcosim::app
