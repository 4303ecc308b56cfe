#include "mujoco_bridge/world.h"

#include <mujoco/mjxmacro.h>
#include <mujoco/mujoco.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <optional>
#include <sstream>
#include <string>
#include <type_traits>
#include <utility>

#include "mesh/error.h"
#include "mesh/generators.h"
#include "mesh/mesh_io.h"
#include "mesh/same_bits.h"
#include "mesh/vector_room.h"
#include "mesh/xml_text.h"
#include "mujoco_bridge/geom_shape.h"
#include "mujoco_bridge/model_names.h"
#include "mujoco_bridge/mujoco_errors.h"
#include "mujoco_bridge/rollout_metrics.h"

namespace tetcosim {
namespace {

// Columns first to first + size - 1 of row `row` of a MuJoCo Jacobian of nv
// columns (efc_J, ten_J), stored sparse (by its rownnz, rowadr, colind: with
// mj_isSparse) or dense
struct MjJacobianRows {
  const double* values;
  const int* rownnz;
  const int* rowadr;
  const int* colind;
};
void JacobianRowSegment(const mjModel* m, const MjJacobianRows& jacobian, int row, int first,
                        Eigen::Ref<Eigen::RowVectorXd> segment) {
  if (!mj_isSparse(m)) {
    segment = Eigen::Map<const Eigen::RowVectorXd>(
        jacobian.values + static_cast<size_t>(row) * m->nv + first, segment.size());
    return;
  }
  segment.setZero();
  for (int e = 0; e < jacobian.rownnz[row]; ++e) {
    const int address = jacobian.rowadr[row] + e;
    const int column = jacobian.colind[address] - first;
    if (column >= 0 && column < segment.size()) segment[column] = jacobian.values[address];
  }
}

// Whether MuJoCo's step takes velocity terms besides the joints' damping
// into the tree's matrix (World::TreeMass): its implicit step and its RK4,
// with an actuator whose force changes with its velocity (an affine gain
// or bias with a velocity term) or a damped tendon (the implicit step
// takes them implicitly, RK4 at each of its stages)
bool StepDampsVelocityTerms(const mjModel* m) {
  if (m->opt.integrator == mjINT_EULER) return false;
  for (int a = 0; a < m->nu; ++a) {
    if ((m->actuator_gaintype[a] == mjGAIN_AFFINE && m->actuator_gainprm[mjNGAIN * a + 2] != 0.0) ||
        (m->actuator_biastype[a] == mjBIAS_AFFINE && m->actuator_biasprm[mjNBIAS * a + 2] != 0.0)) {
      return true;
    }
  }
  return std::any_of(m->tendon_damping, m->tendon_damping + m->ntendon,
                     [](double damping) { return damping > 0.0; });
}

// MuJoCo's matrices are row-major: xmat, ximat, geom_xmat (3 x 3) and the
// Jacobians of mj_jac and mj_jacBody (3 x nv)
using MjRotation = Eigen::Matrix<double, 3, 3, Eigen::RowMajor>;
using MjJacobian = Eigen::Matrix<double, 3, Eigen::Dynamic, Eigen::RowMajor>;

// What a tetrahedron costs in memory once loaded, measured as the peak
// resident size of `tetcosim info` over growing resolutions (a box tetbody
// of 663k and 1.57M tets: 1.40 and 1.35 kB each; a box rigidtet of 331k:
// 0.50 kB each), with some margin: a deformable's (mesh, FEM model, body,
// linear system) and a rigid proxy's (mesh only).
constexpr double kBytesPerDeformableTet = 1600.0;
constexpr double kBytesPerProxyTet = 600.0;

// A mesh geom whose convex hull holds more than this times the mesh's own
// volume is warned of: deformables meet its hull.
constexpr double kConvexHullMargin = 1.02;

// Round geoms (spheres, ellipsoids, capsules and cylinders) narrower than
// this many times the gaps between a deformable's surface vertices get a
// proxy (<contact autoproxy>), as the narrower geoms of every kind do: met
// as a geom, one sinks in between the vertices and rolls over them as over
// a bed of nails. Measured (tests/scenarios/ball_test.cc), a 10 cm rigid ball
// rolling down a 20 degree slope on a stiff slab whose surface gaps are
// 1/1.4, 1/2.8 and 1/4.2 of its width (and 1/7.1, on a slab of 144k
// tetrahedra): met as a geom, 0.35, 0.70, 0.81 (0.90) of a rigid ball's
// rate; with a level-3 proxy, 0.93 on each (what the step's resistance and
// the proxy's facets leave).
constexpr double kRoundProxyWidths = 8.0;
// A made proxy of a round geom has facets that turn by about 0.13 rad (a
// sphere or an ellipsoid at level 3, a capsule or a cylinder 12 cells
// across: its rim in 48 segments). The same ball with a level-1 and a
// level-2 proxy (facets of 0.52 and 0.26 rad): 0.72 to 0.95 and 0.86 to
// 0.87 of the rigid rate.
constexpr double kRoundProxyCellsAcross = 12.0;
// A rigid proxy needs a fine surface, not a fine inside: a round geom's
// made proxy is its surface coned to its centre (a sphere or an ellipsoid,
// ConeToPoint: a level-3 sphere in 1280 tetrahedra, not 10,240) or to its
// axis slab by slab (a capsule or a cylinder, ConeToAxis: no tetrahedron
// longer than a slab however long the body). Measured on the terrain
// scene, whose pebble (an ellipsoid) is given a proxy: the collision phase
// took 0.40 ms a step with the solid level-3 mesh, 0.08 with the coned one
// and with a solid level-2 one (1280 tetrahedra each), 0.02 with none. A
// capsule or a cylinder is made fewer cells across (at least 3) while its
// coned mesh would take more than this many tetrahedra (its layers are as
// thick as its cells are wide: a rod 40 radii long is made 4 across, one
// 5 radii long 12). A rod narrower than the gaps inside a soft body much
// larger than the world (a fuzzed scene) took 221 ms a step at 20,000,
// 75 at 8000, 22 with a 3-cell solid proxy.
constexpr double kMaxConedProxyTets = 8000.0;

// A geom is passed over for a deformable whose box lies farther than this
// (m) beyond the geom's bounding sphere or above its plane: room for the
// rounding of the box tests, against which every vertex is still tested.
constexpr double kGeomCullMargin = 1e-9;

// The memory the system can still give (MemAvailable of /proc/meminfo, in
// bytes), or 0 if it cannot tell (then nothing is checked).
double AvailableMemory() {
  std::ifstream meminfo("/proc/meminfo");
  std::string key;
  double kilobytes = 0.0;
  std::string unit;
  while (meminfo >> key >> kilobytes >> unit) {
    if (key == "MemAvailable:") return kilobytes * 1024.0;
  }
  return 0.0;
}

// Placed far from the origin, a body's vertices round to coarser steps than
// its elements resolve (at 1e30 m, all of a 4 cm cube to one point, which then
// "ran" with 38 J of kinetic energy from nowhere): an error when placing it
// changes any element's volume by more than 1e-6 of itself (a rigid
// placement changes none). (Millimetre elements pass at 1e6 m; at 1e7 m
// they change by 1.8e-6.)
void CheckPlacementPrecision(const DeformableBody& body, const std::string& scene_path, int line,
                             const std::string& name) {
  const TetMesh& mesh = body.mesh();
  const Positions& rest = mesh.positions();
  const Positions& x = body.positions();
  double worst = 0.0;
  for (int t = 0; t < mesh.num_tets(); ++t) {
    Eigen::Vector3d a[4], b[4];
    for (int k = 0; k < 4; ++k) {
      a[k] = rest.row(mesh.tets()(t, k)).transpose();
      b[k] = x.row(mesh.tets()(t, k)).transpose();
    }
    const double v0 = SignedTetVolume(a[0], a[1], a[2], a[3]);
    const double v1 = SignedTetVolume(b[0], b[1], b[2], b[3]);
    const double change = std::abs(v1 - v0) / std::abs(v0);
    if (!(change <= worst)) worst = change;  // (NaN stays)
  }
  if (worst <= 1e-6) return;
  char message[256];
  std::snprintf(message, sizeof(message),
                "<tetbody name=\"%s\">: placed %g m from the origin, rounding changes its "
                "elements' volumes by up to %.3g%%; place the scene nearer the origin",
                name.c_str(), x.cwiseAbs().maxCoeff(), 100.0 * worst);
  ThrowAt(scene_path, line, message);
}

// Adds a mesh of num_tets to the scene's estimated memory (`needed`,
// bytes) and throws, at the scene's element, if that is more than is
// available (`limited`: WorldOptions::memory_limit, else the machine's):
// the alternative is the kernel killing the process while it builds the
// meshes, with no word of why.
void CheckMemory(long num_tets, double bytes_per_tet, double& needed, double available,
                 bool limited, const std::string& scene_path, int line,
                 const std::string& element) {
  needed += static_cast<double>(num_tets) * bytes_per_tet;
  if (available <= 0.0 || needed <= available) return;
  char message[512];
  std::snprintf(message, sizeof(message),
                "%s: %ld tetrahedra; the scene's meshes up to this one need about %.3g GB "
                "(%.1f kB a tetrahedron), and %s %.3g GB%s; use a lower resolution or a "
                "coarser mesh",
                element.c_str(), num_tets, needed / 1e9, bytes_per_tet / 1e3,
                limited ? "the memory limit is" : "this machine has", available / 1e9,
                limited ? "" : " available");
  ThrowAt(scene_path, line, message);
}

using Clock = std::chrono::steady_clock;
double MillisecondsSince(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

// The arrays of mjData that mj_resetData sets, besides its time and
// warnings (MuJoCo 2.2.2), with their lengths: what a step undone
// (World::RestoreStepStart) puts back.
struct StateArray {
  mjtNum* mjData::*array;
  int length;
};
std::array<StateArray, 10> StateArrays(const mjModel* m) {
  return {{{&mjData::qpos, m->nq},
           {&mjData::qvel, m->nv},
           {&mjData::act, m->na},
           {&mjData::ctrl, m->nu},
           {&mjData::qfrc_applied, m->nv},
           {&mjData::xfrc_applied, 6 * m->nbody},
           {&mjData::mocap_pos, 3 * m->nmocap},
           {&mjData::mocap_quat, 4 * m->nmocap},
           {&mjData::qacc_warmstart, m->nv},
           {&mjData::userdata, m->nuserdata}}};
}

// The first of qpos, then qvel, that MuJoCo's mj_checkPos or mj_checkVel
// would reset its state for (mju_isBad: not finite, or beyond mjMAXVAL in
// size), or none.
struct BadState {
  bool velocity = false;  // qvel, else qpos
  int index = 0;
};
std::optional<BadState> FirstBadState(const mjModel* m, const mjData* d) {
  for (int i = 0; i < m->nq; ++i) {
    if (mju_isBad(d->qpos[i])) return BadState{false, i};
  }
  for (int i = 0; i < m->nv; ++i) {
    if (mju_isBad(d->qvel[i])) return BadState{true, i};
  }
  return std::nullopt;
}

// A MuJoCo body's motion, world frame: the velocity of its centre of mass
// xipos, its angular velocity, and its spin (angular momentum about xipos,
// with the principal inertia in the inertial frame ximat).
struct BodyMotion {
  Eigen::Vector3d velocity;
  Eigen::Vector3d omega;
  Eigen::Vector3d spin;
};
BodyMotion MotionOf(const mjModel* m, const mjData* d, int body) {
  double velocity[6];  // angular, then linear at xipos (mjOBJ_BODY)
  mj_objectVelocity(m, d, mjOBJ_BODY, body, velocity, 0);
  BodyMotion motion;
  motion.omega = Eigen::Vector3d(velocity[0], velocity[1], velocity[2]);
  motion.velocity = Eigen::Vector3d(velocity[3], velocity[4], velocity[5]);
  const Eigen::Matrix3d R_WI = Eigen::Map<const MjRotation>(d->ximat + 9 * body);
  const Eigen::Vector3d inertia = Eigen::Map<const Eigen::Vector3d>(m->body_inertia + 3 * body);
  motion.spin = R_WI * inertia.cwiseProduct(R_WI.transpose() * motion.omega);
  return motion;
}

// X_WB of a MuJoCo body from xpos / xmat
Eigen::Isometry3d BodyPose(const mjData* d, int body) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.translation() = Eigen::Map<const Eigen::Vector3d>(d->xpos + 3 * body);
  X.linear() = Eigen::Map<const MjRotation>(d->xmat + 9 * body);
  return X;
}

// X moved for t seconds at angular velocity omega and origin velocity v
// (world frame): turned about its origin, shifted
Eigen::Isometry3d Advance(Eigen::Isometry3d X, const Eigen::Vector3d& omega,
                          const Eigen::Vector3d& v, double t) {
  if (omega.norm() > 0.0) {
    X.linear() = Eigen::AngleAxisd(omega.norm() * t, omega.normalized()) * X.linear();
  }
  X.translation() += t * v;
  return X;
}

// the radius of a sphere about a height field's origin that holds it
// (MuJoCo 2.2.2 gives it none); 0 for other geoms
double HeightFieldRadius(const GeomShape& shape) {
  if (shape.type != mjGEOM_HFIELD) return 0.0;
  const double* size = shape.size;
  return std::sqrt(size[0] * size[0] + size[1] * size[1] +
                   std::max(size[2], size[3]) * std::max(size[2], size[3]));
}

// a geom without a name, as "3 of body 'arm'" (or "3 of body 2")
std::string UnnamedGeom(const mjModel* m, int geom) {
  const char* body = mj_id2name(m, mjOBJ_BODY, m->geom_bodyid[geom]);
  return std::to_string(geom) + " of body " +
         (body ? std::string("'") + body + "'" : std::to_string(m->geom_bodyid[geom]));
}

// "name", or "#3 of body 'arm'" for one without a name (for lists)
std::string GeomLabel(const mjModel* m, int geom) {
  const char* name = mj_id2name(m, mjOBJ_GEOM, geom);
  // (appended, not "#" + ...: g++ 12's -Wrestrict misreads the latter here)
  std::string label = name ? name : "#";
  if (!name) label += UnnamedGeom(m, geom);
  return label;
}

// "geom 'name'", or "geom 3 of body 'arm'" for one without a name (for errors)
std::string GeomName(const mjModel* m, int geom) {
  if (const char* name = mj_id2name(m, mjOBJ_GEOM, geom)) return std::string("geom '") + name + "'";
  return "geom " + UnnamedGeom(m, geom);
}

// a tetrahedral mesh of a geom (a mesh: of its convex hull), in the geom's own frame
RawMesh GeomMesh(const mjModel* m, int geom, int resolution, long line, const std::string& path) {
  const double* size = m->geom_size + 3 * geom;
  const int n = std::max(1, resolution);
  switch (m->geom_type[geom]) {
    case mjGEOM_BOX:
      return MakeBox({size[0], size[1], size[2]}, Eigen::Vector3i::Constant(n), 6);
    case mjGEOM_SPHERE:
      return MakeSphere(size[0], std::min(resolution, 4));
    case mjGEOM_ELLIPSOID: {
      RawMesh raw = MakeSphere(1.0, std::min(resolution, 4));
      for (Eigen::Index v = 0; v < raw.positions.rows(); ++v) {
        for (int k = 0; k < 3; ++k) raw.positions(v, k) *= size[k];
      }
      return raw;
    }
    case mjGEOM_CAPSULE:
      return MakeCapsule(size[0], size[1], n);
    case mjGEOM_CYLINDER:
      return MakeCylinder(size[0], size[1], n);
    case mjGEOM_MESH:
      try {
        return ConvexHullTetMesh(m, geom, MeshExtent(m, geom).maxCoeff() / n, GeomName(m, geom));
      } catch (const Error& e) {
        ThrowAt(path, line, std::string("<rigidtet>: ") + e.what());
      }
    default:
      ThrowAt(path, line,
              "<rigidtet>: geom type " + std::to_string(m->geom_type[geom]) +
                  " has no tetrahedral proxy; use box, sphere, ellipsoid, capsule, cylinder or "
                  "mesh (its convex hull), or give a mesh file");
  }
}

// geom `geom`'s frame in its body's (geom_pos, geom_quat)
Eigen::Isometry3d GeomInBody(const mjModel* m, int geom) {
  Eigen::Isometry3d X_BG = Eigen::Isometry3d::Identity();
  X_BG.translation() = Eigen::Map<const Eigen::Vector3d>(m->geom_pos + 3 * geom);
  const double* q = m->geom_quat + 4 * geom;
  X_BG.linear() = Eigen::Quaterniond(q[0], q[1], q[2], q[3]).toRotationMatrix();
  return X_BG;
}

// Whether a geom's type is round (kRoundProxyWidths)
bool IsRound(int type) {
  return type == mjGEOM_SPHERE || type == mjGEOM_ELLIPSOID || type == mjGEOM_CAPSULE ||
         type == mjGEOM_CYLINDER;
}

// About how many tetrahedra ConeToAxis makes of a capsule or a cylinder
// `cells` across (radius, half-length): its side's layers are as thick as
// its cells are wide, each with 8 n triangles and a ring of 4 n edges (two
// tetrahedra each); its ends, at most 12 n^2 (a capsule's caps)
double ConedRoundTets(double radius, double half_length, int cells) {
  const double layers = std::max(1.0, std::round(half_length * cells / radius));
  return 16.0 * cells * (layers + 1.0) + 12.0 * cells * cells;
}

// The proxy made without a <rigidtet> for a geom that is narrow or round
// (ProxyReasonOf): its surface vertices at most `spacing` apart (a box's
// cells, up to 256 along an axis; a mesh's convex hull, its faces split at
// their longest edges, up to 20,000 faces; a sphere or an ellipsoid at
// level 1 to 3 of MakeSphere, whose edges are 1.05 r / 2^level for a
// radius r; a capsule or a cylinder 3 to 64 cells across, fewer while
// kMaxConedProxyTets asks, and as long along it), a round one's surface
// coned to its centre or its axis. Null for a plane or a height field.
// Throws Error for a mesh without a hull.
std::optional<RawMesh> MadeProxyMesh(const mjModel* m, int geom, double spacing, long line,
                                     const std::string& path) {
  const double* size = m->geom_size + 3 * geom;
  // cells along an axis `extent` long, at least `least`, at most `most`
  auto cells = [&](double extent, double least, double most) {
    return static_cast<int>(std::clamp(std::ceil(extent / spacing), least, most));
  };
  switch (m->geom_type[geom]) {
    case mjGEOM_BOX:
      return MakeBox({size[0], size[1], size[2]},
                     {cells(2.0 * size[0], 1.0, 256.0), cells(2.0 * size[1], 1.0, 256.0),
                      cells(2.0 * size[2], 1.0, 256.0)},
                     6);
    case mjGEOM_MESH:
      return ConvexHullTetMesh(m, geom, spacing, GeomName(m, geom));
    case mjGEOM_SPHERE:
    case mjGEOM_ELLIPSOID: {
      const double radius = std::max({size[0], size[1], size[2]});
      const double level = std::ceil(std::log2(1.05 * radius / spacing));
      const int sphere_level = static_cast<int>(std::clamp(level, 1.0, 3.0));
      return ConeToPoint(TetMesh::Build(GeomMesh(m, geom, sphere_level, line, path)),
                         Eigen::Vector3d::Zero());
    }
    case mjGEOM_CAPSULE:
    case mjGEOM_CYLINDER: {
      int across = cells(2.0 * size[0], 3.0, 64.0);
      while (across > 3 && ConedRoundTets(size[0], size[1], across) > kMaxConedProxyTets) {
        --across;
      }
      return ConeToAxis(TetMesh::Build(GeomMesh(m, geom, across, line, path)), size[1]);
    }
    default:
      return std::nullopt;
  }
}

// How far apart a mesh's surface vertices are: the mean diameter of its
// surface triangles' circumcircles, the widest a round hole among their
// corners can be (a grid of cells h wide split along diagonals: sqrt(2) h)
double MeanSurfaceGap(const TetMesh& mesh, const Positions& x) {
  const Triangles& surface = mesh.surface();
  double sum = 0.0;
  long count = 0;
  for (Eigen::Index f = 0; f < surface.rows(); ++f) {
    const Eigen::Vector3d a = x.row(surface(f, 0)).transpose();
    const Eigen::Vector3d b = x.row(surface(f, 1)).transpose();
    const Eigen::Vector3d c = x.row(surface(f, 2)).transpose();
    const double twice_area = (b - a).cross(c - a).norm();
    if (!(twice_area > 0.0)) continue;  // (a flat triangle has no circle)
    // (2 R = |ab| |bc| |ca| / (2 area))
    sum += (b - a).norm() * (c - b).norm() * (a - c).norm() / twice_area;
    ++count;
  }
  return count > 0 ? sum / static_cast<double>(count) : 0.0;
}

// Why a geom `width` wide (GeomPassageWidth) needs a proxy among
// deformables whose surface vertices leave gaps up to `gap` wide
// (MeanSurfaceGap, of `body`), or empty: narrow, it is narrower than the
// gaps and could pass through touching none of them; round, it is
// narrower than kRoundProxyWidths gaps and would sink in between them.
struct ProxyReason {
  bool narrow = false;
  std::string why;
};
ProxyReason ProxyReasonOf(bool round, double width, double gap, const std::string& body) {
  char why[320];
  if (width < gap) {
    std::snprintf(why, sizeof(why),
                  "%.3g m wide, less than the %.3g m gaps between the surface vertices of tetbody "
                  "'%s'",
                  width, gap, body.c_str());
    return {true, why};
  }
  if (!round || !(width < kRoundProxyWidths * gap)) return {};
  // (a ball `width` across sinks this far into a round gap `gap` across)
  const double sag = 0.5 * width - std::sqrt(0.25 * (width * width - gap * gap));
  std::snprintf(why, sizeof(why),
                "round, %.3g m wide, less than %g times the %.3g m gaps between the surface "
                "vertices of tetbody '%s': met as a geom, it would sink up to %.2g m in between "
                "them and roll over them as over a bed of nails",
                width, kRoundProxyWidths, gap, body.c_str(), sag);
  return {false, why};
}

// an MJCF <skin> of a deformable's surface with one bone on the world body:
// the renderer overwrites its vertices every frame (renderer.h)
std::string SkinXml(const DeformableBody& body, const Eigen::Vector4d& rgba,
                    const std::string& name) {
  const TetMesh& mesh = body.mesh();
  const std::vector<int>& surface_vertices = mesh.surface_vertices();
  std::vector<int> index(mesh.num_vertices(), -1);
  for (size_t i = 0; i < surface_vertices.size(); ++i) {
    index[surface_vertices[i]] = static_cast<int>(i);
  }
  std::ostringstream xml;
  xml.precision(9);
  xml << "<skin name=\"" << XmlEscaped(name) << "\" rgba=\"" << rgba.transpose() << "\" vertex=\"";
  for (int v : surface_vertices) xml << body.positions().row(v) << " ";
  xml << "\" face=\"";
  for (Eigen::Index f = 0; f < mesh.surface().rows(); ++f) {
    for (int k = 0; k < 3; ++k) xml << index[mesh.surface()(f, k)] << " ";
  }
  xml << "\">\n<bone body=\"world\" bindpos=\"0 0 0\" bindquat=\"1 0 0 0\" vertid=\"";
  for (size_t i = 0; i < surface_vertices.size(); ++i) xml << i << " ";
  xml << "\" vertweight=\"";
  for (size_t i = 0; i < surface_vertices.size(); ++i) xml << "1 ";
  xml << "\"/>\n</skin>\n";
  return xml.str();
}

// MuJoCo's error on one line, its lines trimmed and joined by "; " (it
// puts where the error is, "Element 'geom', line 4", on a line of its own,
// which then read as a separate message after ours)
std::string OneLine(const std::string& text) {
  std::string joined;
  std::istringstream lines(text);
  for (std::string line; std::getline(lines, line);) {
    const size_t first = line.find_first_not_of(" \t\r");
    if (first == std::string::npos) continue;
    const size_t last = line.find_last_not_of(" \t\r");
    if (!joined.empty()) joined += "; ";
    joined.append(line, first, last - first + 1);
  }
  return joined;
}

// What to do about MuJoCo's fatal error `what`, as "; ..." after it (empty
// where there is nothing to suggest).
std::string MuJoCoErrorAdvice(const mjModel* m, const std::string& what) {
  if (what.find("tack overflow") != std::string::npos) {
    char advice[256];
    std::snprintf(advice, sizeof(advice),
                  "; MuJoCo's stack holds %d numbers (<size nstack>), too few for the "
                  "contacts and constraints here: give the scene a larger one, such as "
                  "<size nstack=\"%d\"/>",
                  m->nstack,
                  m->nstack < 500'000'000 ? 4 * std::max(m->nstack, 1000) : 2'000'000'000);
    return advice;
  }
  if (what.find("allocate") != std::string::npos) {
    return "; the machine is out of memory for the scene";
  }
  return "";
}

// The object a row of mjModel array `field` belongs to, for an error
// message: "geom 'rim'" for row 3 of geom_pos, "" where the rows are not
// objects (mesh vertices, say).
std::string RowOwner(const mjModel* m, const char* field, const char* rows, long row) {
  struct Kind {
    const char* prefix;
    const char* rows;
    mjtObj type;
    const char* noun;
  };
  static const Kind kinds[] = {
      {"body_", "nbody", mjOBJ_BODY, "body"},
      {"jnt_", "njnt", mjOBJ_JOINT, "joint"},
      {"geom_", "ngeom", mjOBJ_GEOM, "geom"},
      {"site_", "nsite", mjOBJ_SITE, "site"},
      {"cam_", "ncam", mjOBJ_CAMERA, "camera"},
      {"light_", "nlight", mjOBJ_LIGHT, "light"},
      {"tendon_", "ntendon", mjOBJ_TENDON, "tendon"},
      {"actuator_", "nu", mjOBJ_ACTUATOR, "actuator"},
      {"sensor_", "nsensor", mjOBJ_SENSOR, "sensor"},
      {"eq_", "neq", mjOBJ_EQUALITY, "equality"},
      {"key_", "nkey", mjOBJ_KEY, "keyframe"},
      {"mat_", "nmat", mjOBJ_MATERIAL, "material"},
      {"pair_", "npair", mjOBJ_PAIR, "contact pair"},
  };
  for (const Kind& kind : kinds) {
    if (std::strncmp(field, kind.prefix, std::strlen(kind.prefix)) != 0 ||
        std::strcmp(rows, kind.rows) != 0) {
      continue;
    }
    std::string owner = kind.noun;
    if (const char* name = mj_id2name(m, kind.type, static_cast<int>(row))) {
      owner.append(" '").append(name).append("'");
    } else {
      owner.append(" ").append(std::to_string(row));
    }
    return owner;
  }
  return "";
}

// Throws, naming the field and its object, if an array of the compiled
// model holds a number that is not finite. MuJoCo 2.2.2 takes "nan" and
// "inf" in a scene with a warning on the console only: a geom at NaN met
// nothing and left NaN in the rollout's metrics, which reported ok.
template <typename T>
void CheckFinite(const mjModel* m, const char* field, const char* rows_name, const T* values,
                 long rows, long cols, const std::string& scene_path) {
  if constexpr (std::is_floating_point_v<T>) {
    for (long i = 0; i < rows * cols; ++i) {
      if (std::isfinite(values[i])) continue;
      const std::string owner = RowOwner(m, field, rows_name, i / cols);
      ThrowAt(scene_path, 0,
              "MuJoCo's model has a number that is not finite (" + std::to_string(values[i]) +
                  ") in " + field + (owner.empty() ? "" : " of " + owner) +
                  "; check that element's numbers in the scene");
    }
  }
}

void CheckModelFinite(const mjModel* m, const std::string& scene_path) {
  MJMODEL_POINTERS_PREAMBLE(m)
#define X(type, name, rows, cols)                                                            \
  CheckFinite(m, #name, #rows, m->name, static_cast<long>(m->rows), static_cast<long>(cols), \
              scene_path);
  MJMODEL_POINTERS
#undef X
  // <option>'s numbers (its timestep has its own check in World::Load,
  // after --timestep)
  const mjOption& o = m->opt;
  auto check_option = [&](const char* attribute, const mjtNum* values, int count) {
    for (int i = 0; i < count; ++i) {
      if (std::isfinite(values[i])) continue;
      ThrowAt(scene_path, 0,
              std::string("MuJoCo's <option> has a number that is not finite in ") + attribute +
                  "; check its attributes");
    }
  };
  check_option("impratio", &o.impratio, 1);
  check_option("tolerance", &o.tolerance, 1);
  check_option("density", &o.density, 1);
  check_option("viscosity", &o.viscosity, 1);
  check_option("gravity", o.gravity, 3);
  check_option("wind", o.wind, 3);
  check_option("magnetic", o.magnetic, 3);
  check_option("o_margin", &o.o_margin, 1);
  check_option("o_solref", o.o_solref, mjNREF);
  check_option("o_solimp", o.o_solimp, mjNIMP);
}

}  // namespace

struct World::Proxy {
  int body = -1;
  std::shared_ptr<const TetMesh> mesh;  // in the body frame
  Positions positions;                  // world frame, at `frame`
  // the body's pose (xpos, xmat) that `positions` were computed at, and how
  // many times they were: 0, 1 (never moved since, as a static body) or 2
  // (more)
  RigidFrame frame;
  int placements = 0;

  Eigen::VectorXd areas;
  double mean_surface_area = 0.0;  // MeanSurfaceVertexArea
  double friction = 0.5;
};

std::optional<long> WholeSteps(double seconds, double dt) {
  const double steps = std::round(seconds / dt);
  if (!(seconds >= 0.0) || !(steps <= kMaxWholeSteps)) return std::nullopt;
  return static_cast<long>(steps);
}

World::~World() {
  if (data_) mj_deleteData(data_);
  if (model_) mj_deleteModel(model_);
}

void World::AddLoadWarnings(const TetMesh& mesh, const std::string& scene_path, long line,
                            const std::string& element, const std::string& file) {
  for (const std::string& warning : mesh.warnings()) {
    std::string text = Where(scene_path, line);
    text.append(": ").append(element).append(": ");
    if (!file.empty()) text.append(file).append(": ");
    load_warnings_.push_back(text.append(warning));
  }
}

std::unique_ptr<World> World::Load(const std::string& scene_path, const WorldOptions& options) {
  std::unique_ptr<World> world(new World());
  world->options_ = options;
  world->scene_ = ParseScene(scene_path);
  const SceneSpec& scene = world->scene_;

  // deformables (their meshes come first: the MJCF gets a skin for each)
  const ContactParams& scene_contact = scene.contact;
  if (scene.slip) world->contact_settings_.slip_velocity = *scene.slip;
  world->contact_settings_.stick = scene.stick;
  if (scene.stick_stiffness) world->contact_settings_.stick_stiffness = *scene.stick_stiffness;
  world->contact_area_ = scene.contact_area;
  std::string skins;
  const double available_memory = options.memory_limit.value_or(AvailableMemory());
  double needed_memory = 0.0;
  // every deformable's raw mesh first (a few dozen bytes a tetrahedron), so
  // that the whole scene's memory is checked before any mesh is built
  std::vector<RawMesh> raw_meshes(scene.tetbodies.size());
  for (size_t i = 0; i < scene.tetbodies.size(); ++i) {
    const TetBodySpec& spec = scene.tetbodies[i];
    RawMesh& raw = raw_meshes[i];
    try {
      raw = spec.file.empty() ? MakeShape(spec.shape, spec.size, spec.resolution, spec.split,
                                          "tetbody '" + spec.name + "'")
                              : ReadRawMesh(spec.file);
    } catch (const Error& e) {
      ThrowAt(scene_path, spec.line,
              std::string("<tetbody name=\"") + spec.name + "\">: " + e.what());
    }
    CheckMemory(raw.tets.rows(), kBytesPerDeformableTet, needed_memory, available_memory,
                options.memory_limit.has_value(), scene_path, spec.line,
                "<tetbody name=\"" + spec.name + "\">");
  }
  for (size_t i = 0; i < scene.tetbodies.size(); ++i) {
    const TetBodySpec& spec = scene.tetbodies[i];
    RawMesh raw = std::move(raw_meshes[i]);
    raw.positions *= spec.scale;
    auto mesh = std::make_shared<TetMesh>(TetMesh::Build(std::move(raw)));
    world->AddLoadWarnings(*mesh, scene_path, spec.line, "<tetbody name=\"" + spec.name + "\">",
                           spec.file);
    auto model = FemModel::Build(mesh, spec.material, spec.name.c_str());
    auto body = std::make_unique<DeformableBody>(model, spec.name);
    body->Reset(spec.pose, spec.velocity);
    CheckPlacementPrecision(*body, scene_path, spec.line, spec.name);
    double kappa = spec.contact.stiffness.value_or(
        scene_contact.stiffness.value_or(DefaultContactPressureStiffness(*model)));
    if (kappa <= 0.0) kappa = DefaultContactPressureStiffness(*model);
    world->kappa_.push_back(kappa);
    world->mean_surface_area_.push_back(MeanSurfaceVertexArea(*mesh, model->contact_areas()));
    world->friction_.push_back(
        spec.contact.friction.value_or(scene_contact.friction.value_or(0.5)));
    world->damping_.push_back(spec.contact.damping.value_or(scene_contact.damping.value_or(0.5)));
    world->attach_bodies_.emplace_back();
    skins += SkinXml(*body, spec.rgba, "tetcosim_" + spec.name);
    world->body_pointers_.push_back(body.get());
    world->bodies_.push_back(std::move(body));
  }
  std::string mjcf = scene.mjcf;
  if (!skins.empty()) {
    size_t close = mjcf.rfind("</mujoco>");
    if (close == std::string::npos) ThrowAt(scene_path, 0, "the scene has no closing </mujoco>");
    mjcf.insert(close, "<asset>\n" + skins + "</asset>\n");  // MuJoCo 2.2: skins are assets
  }

  // the MJCF without <deformable>, handed to MuJoCo from memory under a name
  // in the scene's own folder, so that relative includes and assets resolve
  // (MuJoCo 2.2.2 matches VFS names by basename: pick one nothing else uses)
  std::filesystem::path directory = std::filesystem::absolute(scene_path).parent_path();
  const std::string vfs_name = "tetcosim-scene-" + std::to_string(::getpid()) + "-" +
                               std::to_string(reinterpret_cast<std::uintptr_t>(world.get())) +
                               ".xml";
  auto vfs = std::make_unique<mjVFS>();  // about 2 MB: on the heap
  mj_defaultVFS(vfs.get());
  if (mj_makeEmptyFileVFS(vfs.get(), vfs_name.c_str(), static_cast<int>(mjcf.size())) != 0) {
    ThrowAt(scene_path, 0, "could not create the in-memory scene file");
  }
  std::memcpy(vfs->filedata[vfs->nfile - 1], mjcf.data(), mjcf.size());
  char error[1000] = "";
  const std::string load_name = (directory / vfs_name).string();
  std::optional<std::string> fatal;  // a fatal error MuJoCo raised in loading
  try {
    CallMuJoCo(
        [&] { world->model_ = mj_loadXML(load_name.c_str(), vfs.get(), error, sizeof(error)); });
  } catch (const MuJoCoError& e) {
    fatal = e.what();
  }
  mj_deleteVFS(vfs.get());
  if (fatal) ThrowAt(scene_path, 0, "MuJoCo failed loading the scene: " + *fatal);
  if (!world->model_) {
    std::string message = error;
    // MuJoCo names our in-memory file; the user knows the scene's
    size_t at = message.find(vfs_name);
    if (at != std::string::npos) {
      message.replace(at, vfs_name.size(), std::filesystem::path(scene_path).filename().string());
    }
    ThrowAt(scene_path, 0, "MuJoCo rejected the scene: " + OneLine(message));
  }
  mjModel* m = world->model_;
  CheckModelFinite(m, scene_path);
  // (MuJoCo takes a negative damping: it adds energy, and MuJoCo's step
  // with it, M + dt B, and the deformables' step with it, lose definiteness:
  // a lid damped -1 N m s was flung at 1e10 J in 0.2 s)
  for (int dof = 0; dof < m->nv; ++dof) {
    if (m->dof_damping[dof] >= 0.0) continue;
    char damping[64];
    std::snprintf(damping, sizeof(damping), " has damping %g < 0", m->dof_damping[dof]);
    ThrowAt(scene_path, 0,
            RowOwner(m, "jnt_damping", "njnt", m->dof_jntid[dof]) + " of " +
                RowOwner(m, "body_", "nbody", m->dof_bodyid[dof]) + damping +
                ", which adds energy (MuJoCo's step with it diverges); give 0 or more");
  }
  if (options.timestep) m->opt.timestep = *options.timestep;
  // (MuJoCo takes any number: at -0.001 s a rollout "ran" backwards in time
  // and reported ok)
  if (!(m->opt.timestep > 0.0) || !std::isfinite(m->opt.timestep)) {
    char message[128];
    std::snprintf(message, sizeof(message),
                  "the time step is %g s (<option timestep>); give a finite time > 0",
                  m->opt.timestep);
    ThrowAt(scene_path, 0, message);
  }
  try {
    CallMuJoCo([&] {
      world->data_ = mj_makeData(m);
      // the first keyframe is the initial state
      if (m->nkey > 0) mj_resetDataKeyframe(m, world->data_, 0);
      mj_forward(m, world->data_);
    });
  } catch (const MuJoCoError& e) {
    ThrowAt(scene_path, 0,
            std::string("MuJoCo failed computing the scene's initial state: ") + e.what() +
                MuJoCoErrorAdvice(m, e.what()));
  }
  mjData* d = world->data_;
  // a state MuJoCo would reset at the first step
  if (const std::optional<BadState> bad = FirstBadState(m, d)) {
    std::ostringstream message;
    message << "the initial state (" << (m->nkey > 0 ? "the first keyframe" : "the model's")
            << ") has " << (bad->velocity ? "qvel[" : "qpos[") << bad->index
            << "] = " << (bad->velocity ? d->qvel : d->qpos)[bad->index]
            << ", which MuJoCo does not step (it takes values up to " << mjMAXVAL
            << " in size); give the joint a smaller one";
    ThrowAt(scene_path, 0, message.str());
  }

  // rigid proxies
  world->geom_has_proxy_.assign(m->ngeom, 0);
  // body `body`'s proxy from `raw` (mesh frame), placed at X_BM in the body
  // frame
  auto add_proxy = [&](int body, RawMesh raw, const Eigen::Isometry3d& X_BM, double friction,
                       long line, const std::string& file) {
    auto proxy = std::make_unique<Proxy>();
    proxy->body = body;
    proxy->friction = friction;
    CheckMemory(raw.tets.rows(), kBytesPerProxyTet, needed_memory, available_memory,
                options.memory_limit.has_value(), scene_path, line, "<rigidtet>");
    for (Eigen::Index v = 0; v < raw.positions.rows(); ++v) {
      raw.positions.row(v) = (X_BM * raw.positions.row(v).transpose()).transpose();
    }
    proxy->mesh = std::make_shared<TetMesh>(TetMesh::Build(std::move(raw)));
    world->AddLoadWarnings(*proxy->mesh, scene_path, line, "<rigidtet>", file);
    proxy->areas = ComputeContactAreas(*proxy->mesh);
    proxy->mean_surface_area = MeanSurfaceVertexArea(*proxy->mesh, proxy->areas);
    proxy->positions = proxy->mesh->positions();
    world->proxies_.push_back(std::move(proxy));
  };
  for (const RigidTetSpec& spec : scene.rigidtets) {
    int body = mj_name2id(m, mjOBJ_BODY, spec.body.c_str());
    if (body < 0) {
      ThrowAt(scene_path, spec.line,
              "<rigidtet>: no MuJoCo body named '" + spec.body + "'; the scene has " +
                  NamesOf(m, mjOBJ_BODY));
    }
    RawMesh raw;
    Eigen::Isometry3d X_BM = spec.pose;
    double friction = 0.5;
    if (!spec.geom.empty()) {
      int geom = mj_name2id(m, mjOBJ_GEOM, spec.geom.c_str());
      if (geom < 0 || m->geom_bodyid[geom] != body) {
        ThrowAt(scene_path, spec.line,
                "<rigidtet>: " +
                    (geom < 0
                         ? "no geom named '" + spec.geom + "'"
                         : "geom '" + spec.geom + "' does not belong to body '" + spec.body + "'") +
                    "; body '" + spec.body + "' has " + NamesOf(m, mjOBJ_GEOM, body));
      }
      raw = GeomMesh(m, geom, spec.resolution, spec.line, scene_path);
      X_BM = GeomInBody(m, geom);
      world->geom_has_proxy_[geom] = 1;
      friction = m->geom_friction[3 * geom];
    } else {
      try {
        raw = ReadRawMesh(spec.file);
      } catch (const Error& e) {
        ThrowAt(scene_path, spec.line, std::string("<rigidtet>: ") + e.what());
      }
    }
    raw.positions *= spec.scale;
    add_proxy(body, std::move(raw), X_BM, friction, spec.line, spec.file);
  }

  // attachments: pins that follow a MuJoCo body. A glued tetbody's `pos`
  // and its regions are in the model's own pose, where the MJCF puts the
  // bodies (qpos0), as MuJoCo's own bodies are: it starts where the first
  // keyframe takes the bodies it is glued to (PlaceGluedTetbodies)
  const std::vector<Eigen::Isometry3d> moved = world->PlaceGluedTetbodies(scene_path);
  for (const AttachSpec& spec : scene.attachments) {
    int index = world->DeformableIndex(spec.tetbody);
    int body = mj_name2id(m, mjOBJ_BODY, spec.body.c_str());
    DeformableBody& deformable = *world->bodies_[index];
    const Eigen::Isometry3d to_own_pose = moved[index].inverse();
    std::vector<int> vertices;
    for (int v : spec.vertices) {
      if (v >= deformable.num_vertices()) {
        ThrowAt(scene_path, spec.line,
                "<attach>: vertex " + std::to_string(v) + " is out of range (" +
                    std::to_string(deformable.num_vertices()) + " vertices)");
      }
      vertices.push_back(v);
    }
    for (int v = 0; v < deformable.num_vertices(); ++v) {
      const Eigen::Vector3d p = to_own_pose * deformable.positions().row(v).transpose();
      if (spec.box && (p.array() >= spec.box->first.array()).all() &&
          (p.array() <= spec.box->second.array()).all()) {
        vertices.push_back(v);
      }
      if (spec.sphere && (p - spec.sphere->first).norm() <= spec.sphere->second) {
        vertices.push_back(v);
      }
    }
    if (vertices.empty()) {
      ThrowAt(scene_path, spec.line,
              "<attach>: the region holds no vertex of '" + spec.tetbody + "'");
    }
    // (a vertex glued to two bodies would be torn between them)
    const std::vector<int>& pinned = deformable.pinned_vertices();
    for (int v : vertices) {
      auto it = std::lower_bound(pinned.begin(), pinned.end(), v);
      if (it == pinned.end() || *it != v) continue;
      const int other = world->PinBody(index, static_cast<size_t>(it - pinned.begin()));
      if (other >= 0 && other != body) {
        ThrowAt(scene_path, spec.line,
                "<attach>: vertex " + std::to_string(v) + " of tetbody '" + spec.tetbody +
                    "' is glued to body '" + world->RigidBodyName(other) +
                    "' already; a vertex follows one body: make the regions apart");
      }
    }
    deformable.PinToFrame(vertices, BodyPose(d, body));
    world->attach_bodies_[index].push_back(body);
    // With <solver rigid="explicit">, an attachment acts on its body after
    // the step: a body much lighter than the deformable it carries takes
    // the deformable's inertia a step late and diverges, whatever the time
    // step (measured: a 15 g pad of E = 5e4 to 1e8 Pa glued to a body on
    // slide joints, 1 ms: diverged from 40 g down, stable from 45 g; with 2
    // substeps from 15 g down, stable from 18 g; at 0.2 ms, 40 g still
    // diverged). Implicit (the default), the body's tree carries the pins
    // within the step (RigidPin). A body welded to the world, or to a mocap
    // body, takes no force (MuJoCo gives it no degree of freedom).
    const double glued = deformable.model().masses().sum();
    const double carrier = m->body_subtreemass[body];
    const double factor = scene.solver.substeps > 1 ? 1.5 : 3.0;
    if (!scene.solver.implicit_rigid && m->body_weldid[body] != 0 && carrier < factor * glued) {
      char message[512];
      std::snprintf(message, sizeof(message),
                    "<attach>: tetbody '%s' (%.3g kg) is glued to body '%s', which with what it "
                    "carries weighs %.3g kg: with rigid=\"explicit\", attachments act on their "
                    "body after the step, which diverges when the body weighs less than about "
                    "%g times what is glued to it; leave <solver rigid> implicit (the default), "
                    "or make the body heavier or the deformable lighter%s",
                    spec.tetbody.c_str(), glued, spec.body.c_str(), carrier, factor,
                    scene.solver.substeps > 1 ? "" : ", or use substeps=\"2\" (1.5 times)");
      world->load_warnings_.push_back(Where(scene_path, spec.line) + ": " + message);
    }
  }

  // the geoms deformables meet by their shapes: those that collide with
  // them (contype or conaffinity with bit 0 set: a deformable's are both 1)
  // and have no proxy. A geom narrower than the gaps between a deformable's
  // surface vertices can sink in between them, touching none, and pass
  // through the body (a 12 mm ball fell through a block whose surface
  // vertices are 33 mm apart, tests/scenarios/small_geom_test.cc): such a
  // geom gets a proxy made for it (<contact autoproxy>; a mesh, of its
  // convex hull), whose vertices meet the deformable's tetrahedra, or with
  // autoproxy off a warning. So does a round geom up to kRoundProxyWidths
  // times as wide (without a warning when autoproxy is off or narrow): it
  // would sink in between them and roll over them (ProxyReasonOf).
  double gap = 0.0;  // the coarsest deformable's (MeanSurfaceGap)
  std::string coarsest;
  for (const auto& body : world->bodies_) {
    const double body_gap = MeanSurfaceGap(body->mesh(), body->positions());
    if (body_gap > gap) {
      gap = body_gap;
      coarsest = body->name();
    }
  }
  for (int g = 0; g < m->ngeom; ++g) {
    if (world->geom_has_proxy_[g]) continue;
    if (!(m->geom_contype[g] & 1) && !(m->geom_conaffinity[g] & 1)) continue;
    const std::string name = GeomName(m, g);
    const double width = GeomPassageWidth(m, g);
    const bool round = IsRound(m->geom_type[g]);
    const ProxyReason reason = ProxyReasonOf(round, width, gap, coarsest);
    const bool wanted = reason.narrow ? scene.auto_proxies != AutoProxies::kNone
                                      : scene.auto_proxies == AutoProxies::kNarrowAndRound;
    if (!reason.why.empty() && (reason.narrow || wanted)) {
      std::string unmade;  // why no proxy could be made, if one was tried
      if (wanted) {
        try {
          const double spacing = round ? width / kRoundProxyCellsAcross : 0.5 * width;
          std::optional<RawMesh> raw = MadeProxyMesh(m, g, spacing, 0, scene_path);
          if (raw) {
            const int num_tets = static_cast<int>(raw->tets.rows());
            add_proxy(m->geom_bodyid[g], std::move(*raw), GeomInBody(m, g), m->geom_friction[3 * g],
                      0, "");
            world->geom_has_proxy_[g] = 1;
            world->made_proxies_.push_back({GeomLabel(m, g), reason.why, num_tets});
            continue;
          }
        } catch (const Error& e) {  // (a hull with a flat face, say: warned of instead)
          unmade = std::string(" (no proxy could be made of it: ") + e.what() + ")";
        }
      }
      std::string warning = Where(scene_path);
      warning.append(": ").append(name).append(": ").append(reason.why);
      if (reason.narrow) {
        warning.append(
            " (deformables meet geoms at their vertices: it can sink in between them, touching "
            "none, and pass through if it fits)");
      }
      warning.append(unmade).append(
          wanted ? "; give it a <rigidtet> with a tetrahedral mesh of it, or refine the tetbody"
                 : "; give it a <rigidtet>, or leave autoproxy on, or refine the tetbody");
      world->load_warnings_.push_back(std::move(warning));
    }
    try {
      world->geom_shapes_.emplace_back(g, MakeGeomShape(m, g, name));
    } catch (const Error& e) {
      ThrowAt(scene_path, 0, e.what());
    }
    const GeomShape& shape = world->geom_shapes_.back().second;
    if (shape.type == mjGEOM_MESH && shape.hull_volume > kConvexHullMargin * shape.mesh_volume) {
      char message[400];
      std::snprintf(message, sizeof(message),
                    "%s: its mesh is not convex, or its faces do not close it (its convex hull "
                    "holds %.3g times what they enclose); "
                    "deformables meet the hull, as MuJoCo's bodies do; for its own shape give the "
                    "geom a <rigidtet> with a tetrahedral mesh of it (tetgen, gmsh)",
                    name.c_str(), shape.hull_volume / shape.mesh_volume);
      world->load_warnings_.push_back(Where(scene_path) + ": " + message);
    }
  }

  // each tree's degrees of freedom (MuJoCo numbers them body by body, bodies
  // depth first: a tree's are consecutive), by the tree's root body
  world->tree_first_dof_.assign(m->nbody, -1);
  world->tree_num_dofs_.assign(m->nbody, 0);
  world->tree_damped_.assign(m->nbody, 0);
  world->damps_velocity_terms_ = StepDampsVelocityTerms(m);
  for (int dof = 0; dof < m->nv; ++dof) {
    const int root = m->body_rootid[m->dof_bodyid[dof]];
    if (m->dof_damping[dof] > 0.0 || world->damps_velocity_terms_) world->tree_damped_[root] = 1;
    if (world->tree_first_dof_[root] < 0) world->tree_first_dof_[root] = dof;
    if (world->tree_first_dof_[root] + world->tree_num_dofs_[root] != dof) {
      throw Error(scene_path + ": MuJoCo's degrees of freedom of the tree of body '" +
                  world->RigidBodyName(root) +
                  "' are not consecutive, which tetcosim relies on; please report this scene");
    }
    ++world->tree_num_dofs_[root];
  }
  world->tree_slot_.assign(m->nbody, -1);
  world->tree_carried_.assign(m->nbody, 0);
  world->tree_solved_.assign(m->nbody, 0);
  world->substep_pose_.resize(m->nbody);
  world->substep_moved_.assign(m->nbody, 0);
  world->ours_.assign(6 * m->nbody, 0.0);
  world->user_.assign(6 * m->nbody, 0.0);
  world->written_.assign(6 * m->nbody, 0.0);
  world->accumulated_.assign(6 * m->nbody, 0.0);
  PenetrationOptions penetration;
  penetration.method = options.method.value_or(scene.method);
  penetration.num_threads = options.threads;
  world->solver_.set_options(penetration);
  penetration.method = DepthMethod::kClosest;
  world->exact_solver_.set_options(penetration);
  world->step_settings_.gravity = Eigen::Map<const Eigen::Vector3d>(m->opt.gravity);
  world->step_settings_.solver = scene.solver.linear_solver;
  world->step_settings_.cg_tolerance = scene.solver.tolerance;
  world->step_settings_.cg_max_iterations = scene.solver.max_iterations;
  world->step_settings_.num_threads = options.threads;
  world->WarnOfStartingOverlaps(scene_path);
  return world;
}

std::vector<Eigen::Isometry3d> World::PlaceGluedTetbodies(const std::string& scene_path) {
  const mjModel* m = model_;
  const mjData* d = data_;
  std::vector<Eigen::Isometry3d> moved(bodies_.size(), Eigen::Isometry3d::Identity());
  // each tetbody's bodies, in <attach> order
  std::vector<std::vector<std::pair<int, const AttachSpec*>>> glued(bodies_.size());
  for (const AttachSpec& spec : scene_.attachments) {
    const int body = mj_name2id(m, mjOBJ_BODY, spec.body.c_str());
    if (body < 0) {
      ThrowAt(scene_path, spec.line,
              "<attach>: no MuJoCo body named '" + spec.body + "'; the scene has " +
                  NamesOf(m, mjOBJ_BODY));
    }
    glued[DeformableIndex(spec.tetbody)].emplace_back(body, &spec);
  }
  if (m->nkey == 0) return moved;
  mjData* own = nullptr;  // the model's own pose
  CallMuJoCo([&] {
    own = mj_makeData(m);
    mj_kinematics(m, own);
  });
  const std::unique_ptr<mjData, void (*)(mjData*)> free_own(own, mj_deleteData);
  // (exactly: a body the keyframe leaves in place moves nothing)
  auto same_pose = [&](int body) {
    return std::equal(d->xpos + 3 * body, d->xpos + 3 * body + 3, own->xpos + 3 * body) &&
           std::equal(d->xmat + 9 * body, d->xmat + 9 * body + 9, own->xmat + 9 * body);
  };
  for (size_t i = 0; i < bodies_.size(); ++i) {
    if (glued[i].empty()) continue;
    DeformableBody& deformable = *bodies_[i];
    const int first = glued[i][0].first;
    const Eigen::Isometry3d move = BodyPose(d, first) * BodyPose(own, first).inverse();
    // how far another body's move would put the tetbody's vertices from
    // where the first's does
    double size = 0.0;
    for (int k = 0; k < deformable.num_vertices(); ++k) {
      size = std::max(size, deformable.positions().row(k).norm());
    }
    for (const auto& [body, spec] : glued[i]) {
      if (body == first || (same_pose(body) && same_pose(first))) continue;
      const Eigen::Isometry3d other = BodyPose(d, body) * BodyPose(own, body).inverse();
      double apart = 0.0;
      for (int k = 0; k < deformable.num_vertices(); ++k) {
        const Eigen::Vector3d x = deformable.positions().row(k).transpose();
        apart = std::max(apart, (other * x - move * x).norm());
      }
      if (apart > 1e-9 * std::max(1.0, size)) {
        char message[500];
        std::snprintf(message, sizeof(message),
                      "<attach>: the first keyframe moves body '%s' and body '%s' apart, by up "
                      "to %.3g m at tetbody '%s', which is glued to both where the model's own "
                      "pose (qpos0) puts them; glue it to one of them, or start from a keyframe "
                      "that keeps them as they are in the model",
                      glued[i][0].second->body.c_str(), spec->body.c_str(), apart,
                      deformable.name().c_str());
        ThrowAt(scene_path, spec->line, message);
      }
    }
    if (!same_pose(first)) {
      const TetBodySpec& spec = scene_.tetbodies[i];
      deformable.Reset(move * spec.pose, spec.velocity);
      moved[i] = move;
    }
    const bool one_body = std::all_of(glued[i].begin(), glued[i].end(),
                                      [&](const auto& entry) { return entry.first == first; });
    if (!one_body) continue;
    Positions& v = deformable.mutable_velocities();
    for (int k = 0; k < deformable.num_vertices(); ++k) {
      v.row(k) +=
          RigidBodyPointVelocity(first, deformable.positions().row(k).transpose()).transpose();
    }
  }
  return moved;
}

// Bodies placed inside each other (two soft cubes overlapping by half: the
// contacts threw them apart with 12 J, and the run said ok) are warned
// of, a pair each, when the deepest point of one in the other is deeper
// than the rollout metrics' sticking threshold, 5% of the thinner
// deformable's thickness (a body resting on another is not deep in it).
void World::WarnOfStartingOverlaps(const std::string& scene_path) {
  const int num_deformables = static_cast<int>(bodies_.size());
  const double fraction = RolloutMetricsOptions{}.sticking_fraction;
  std::map<std::pair<int, int>, Interpenetration> deepest;  // by pair, lower object first
  for (const Interpenetration& point : MeasureInterpenetration()) {
    const std::pair<int, int> pair = std::minmax(point.inside, point.penetrated);
    auto [it, added] = deepest.emplace(pair, point);
    if (!added && point.depth > it->second.depth) it->second = point;
  }
  auto thickness = [&](int object) {
    return object < num_deformables ? Thickness(bodies_[object]->mesh())
                                    : std::numeric_limits<double>::infinity();
  };
  auto label = [&](int object) {
    if (object < num_deformables) return "tetbody '" + bodies_[object]->name() + "'";
    const int body = object - num_deformables;
    return body == 0 ? std::string("the world's geoms") : "body '" + RigidBodyName(body) + "'";
  };
  for (const auto& [pair, point] : deepest) {
    const double thinner = std::min(thickness(pair.first), thickness(pair.second));
    if (!(point.depth > fraction * thinner)) continue;
    // (named by a deformable of the pair, on that tetbody's line)
    const int deformable = point.inside < num_deformables ? point.inside : point.penetrated;
    char message[512];
    std::snprintf(message, sizeof(message),
                  "%s starts %.3g m inside %s, %.0f%% of the thinner deformable's thickness "
                  "(%.3g m): contact pushes them apart at once, as hard as that depth; place "
                  "them apart",
                  label(point.inside).c_str(), point.depth, label(point.penetrated).c_str(),
                  100.0 * point.depth / thinner, thinner);
    load_warnings_.push_back(
        Where(scene_path, scene_.tetbodies[static_cast<size_t>(deformable)].line) +
        ": <tetbody name=\"" + bodies_[deformable]->name() + "\">: " + message);
  }
}

double World::time() const {
  return data_->time;
}
double World::timestep() const {
  return model_->opt.timestep;
}

int World::BodyId(const std::string& name) const {
  return mj_name2id(model_, mjOBJ_BODY, name.c_str());
}

double* World::controls() {
  return data_->ctrl;
}
int World::num_controls() const {
  return model_->nu;
}

int World::num_rigid_bodies() const {
  return model_->nbody;
}

std::string World::RigidBodyName(int body) const {
  const char* name = mj_id2name(model_, mjOBJ_BODY, body);
  return name ? name : "body" + std::to_string(body);
}

Eigen::Vector3d World::RigidBodyPosition(int body) const {
  return Eigen::Map<const Eigen::Vector3d>(data_->xpos + 3 * body);
}

Eigen::Quaterniond World::RigidBodyOrientation(int body) const {
  const double* q = data_->xquat + 4 * body;
  return Eigen::Quaterniond(q[0], q[1], q[2], q[3]);
}

// (mj_objectVelocity gives the velocity of the point it is asked about:
// for mjOBJ_BODY the centre of mass xipos, for mjOBJ_XBODY the origin xpos)
Eigen::Vector3d World::RigidBodyLinearVelocity(int body) const {
  double velocity[6];
  mj_objectVelocity(model_, data_, mjOBJ_XBODY, body, velocity, 0);
  return Eigen::Vector3d(velocity[3], velocity[4], velocity[5]);
}

Eigen::Vector3d World::RigidBodyAngularVelocity(int body) const {
  double velocity[6];
  mj_objectVelocity(model_, data_, mjOBJ_BODY, body, velocity, 0);
  return Eigen::Vector3d(velocity[0], velocity[1], velocity[2]);
}

int World::DeformableIndex(const std::string& name) const {
  for (size_t i = 0; i < bodies_.size(); ++i) {
    if (bodies_[i]->name() == name) return static_cast<int>(i);
  }
  return -1;
}

Eigen::Vector3d World::RigidBodyPointVelocity(int body, const Eigen::Vector3d& p) const {
  if (body <= 0) return Eigen::Vector3d::Zero();
  double velocity[6];  // angular, then linear at the body origin xpos, world frame
  mj_objectVelocity(model_, data_, mjOBJ_XBODY, body, velocity, 0);
  Eigen::Vector3d omega(velocity[0], velocity[1], velocity[2]);
  Eigen::Vector3d v(velocity[3], velocity[4], velocity[5]);
  return v + omega.cross(p - Eigen::Map<const Eigen::Vector3d>(data_->xpos + 3 * body));
}

double World::RigidBodyRadius(int body) const {
  if (body <= 0) return 0.0;
  const mjModel* m = model_;
  const Eigen::Map<const Eigen::Vector3d> com(data_->xipos + 3 * body);
  double radius = 0.0;
  for (int k = 0; k < m->body_geomnum[body]; ++k) {
    const int g = m->body_geomadr[body] + k;
    radius = std::max(radius,
                      (Eigen::Map<const Eigen::Vector3d>(data_->geom_xpos + 3 * g) - com).norm() +
                          m->geom_rbound[g]);
  }
  if (m->body_geomnum[body] > 0 || m->body_mass[body] <= 0.0) return radius;
  const double* inertia = m->body_inertia + 3 * body;
  return std::sqrt((inertia[0] + inertia[1] + inertia[2]) / (2.0 * m->body_mass[body]));
}

World::PointMotion World::RigidPointMotion(int body, const Eigen::Vector3d& p, double dt) const {
  PointMotion motion;
  if (body <= 0) return motion;
  double velocity[6];  // angular, then linear at the body origin xpos, world frame
  mj_objectVelocity(model_, data_, mjOBJ_XBODY, body, velocity, 0);
  const Eigen::Vector3d omega(velocity[0], velocity[1], velocity[2]);
  const Eigen::Vector3d v(velocity[3], velocity[4], velocity[5]);
  // the point's arm from the body's origin, now and at the step's start
  // (where the step takes its velocity, as MuJoCo's Jacobians do); they
  // differ in a later substep, the body having turned
  const Eigen::Vector3d r = p - SubstepPose(body).translation();
  const Eigen::Vector3d r_0 =
      AtStepStart(body, p) - Eigen::Map<const Eigen::Vector3d>(data_->xpos + 3 * body);
  motion.velocity = v + omega.cross(r_0);
  const double angle = omega.norm() * dt;
  if (angle == 0.0) return motion;
  // (R - I) r - angle k x r, R the turn by `angle` about k: Rodrigues'
  // formula less its first-order term, (sin a - a) k x r + (1 - cos a) k x
  // (k x r), with 1 - cos a = 2 sin^2(a / 2) (no cancellation)
  const Eigen::Vector3d k = omega / omega.norm();
  const double half_sine = std::sin(0.5 * angle);
  motion.arc =
      ((std::sin(angle) - angle) * k.cross(r) + 2.0 * half_sine * half_sine * k.cross(k.cross(r))) /
          dt +
      omega.cross(r - r_0);
  return motion;
}

// Where a deformable's momentum changes in a step, x0 x dp about the
// world origin, x0 its positions at the step's start (backward Euler moves
// a vertex by dt times its new velocity): a reaction applied at those
// points, as MuJoCo applies it about the centre of mass at the step's start,
// leaves the total angular momentum exactly unchanged.
void World::KeepReactionPoints() {
  reaction_points_.clear();
  // (on the rigid body: where the point is in the pose at the step's start,
  // at which MuJoCo applies the reactions)
  for (size_t c = 0; c < contacts_.size(); ++c) {
    if (contact_rigid_body_[c] < 0) continue;
    const ContactPoint& contact = contacts_[c];
    const int rigid = contact_rigid_body_[c];
    if (contact.body_a >= 0) {
      reaction_points_.push_back(AtStepStart(
          rigid, bodies_[contact.body_a]->positions().row(contact.vertex_a).transpose()));
      continue;
    }
    // a proxy vertex inside a deformable: its place in the containing tetrahedron
    const DeformableBody& body = *bodies_[contact.body_b];
    const auto tet = body.mesh().tets().row(contact.tet_b);
    Eigen::Vector3d point = Eigen::Vector3d::Zero();
    for (int k = 0; k < 4; ++k) {
      point += contact.barycentric_b[k] * body.positions().row(tet[k]).transpose();
    }
    reaction_points_.push_back(AtStepStart(rigid, point));
  }
  for (size_t i = 0; i < bodies_.size(); ++i) {
    const std::vector<int>& pinned = bodies_[i]->pinned_vertices();
    for (size_t k = 0; k < pinned.size(); ++k) {
      const int body = PinBody(i, k);
      if (body < 0) continue;
      reaction_points_.push_back(
          AtStepStart(body, bodies_[i]->positions().row(pinned[k]).transpose()));
    }
  }
}

// The generalized forces besides ours: MuJoCo's actuators now (mj_step2
// computes them again from the same state), the user's body forces, the
// rest as MuJoCo holds them (once a step: the same in every substep).
void World::FindOtherForces() {
  if (other_forces_ready_) return;
  const mjModel* m = model_;
  mjData* d = data_;
  CallMuJoCo([&] { mj_fwdActuation(m, d); });
  if (LinearizedConstraints()) {
    // this step's constraint rows solved with the last step's forces of
    // ours: their active set, and the forces of the rows not linearized
    CallMuJoCo([&] {
      mj_fwdAcceleration(m, d);
      mj_fwdConstraint(m, d);
    });
    AssignWithRoom(row_trees_, static_cast<size_t>(d->nefc), std::array<int, 2>{-1, -1});
    // J qacc, each row's rate at MuJoCo's solution
    ResizeWithRoom(constraint_rates_, static_cast<size_t>(d->nefc));
    mj_mulJacVec(m, d, constraint_rates_.data(), d->qacc);
    const bool sparse = mj_isSparse(m) != 0;
    for (int first = 0, rows = 1; first < d->nefc; first += rows) {
      rows = ConstraintRows(first);
      std::array<int, 2>& trees = row_trees_[static_cast<size_t>(first)];
      for (int i = first; i < first + rows && trees[0] != -2; ++i) {
        const int count = sparse ? d->efc_J_rownnz[i] : m->nv;
        for (int k = 0; k < count; ++k) {
          const int dof = sparse ? d->efc_J_colind[d->efc_J_rowadr[i] + k] : k;
          if (!sparse && d->efc_J[static_cast<size_t>(i) * m->nv + k] == 0.0) continue;
          const int root = m->body_rootid[m->dof_bodyid[dof]];
          if (trees[0] < 0 || trees[0] == root) {
            trees[0] = root;
          } else if (trees[1] < 0 || trees[1] == root) {
            trees[1] = root;
          } else {
            trees = {-2, -2};  // (three trees or more: not linearized)
            break;
          }
        }
      }
    }
  }
  other_forces_.assign(m->nv, 0.0);
  for (int b = 1; b < m->nbody; ++b) {
    const double* user = user_.data() + 6 * b;
    if (std::all_of(user, user + 6, [](double x) { return x == 0.0; })) continue;
    CallMuJoCo(
        [&] { mj_applyFT(m, d, user, user + 3, d->xipos + 3 * b, b, other_forces_.data()); });
  }
  for (int i = 0; i < m->nv; ++i) {
    other_forces_[i] += d->qfrc_passive[i] - d->qfrc_bias[i] + d->qfrc_actuator[i] +
                        d->qfrc_applied[i] + d->qfrc_constraint[i];
  }
  other_forces_ready_ = true;
}

bool World::LinearizedConstraints() const {
  return scene_.solver.implicit_rigid && scene_.solver.linearize_constraints;
}

int World::ConstraintRows(int row) const {
  return data_->efc_type[row] == mjCNSTR_CONTACT_ELLIPTIC ? data_->contact[data_->efc_id[row]].dim
                                                          : 1;
}

// MuJoCo's force of a constraint row i in its quadratic state (an equality,
// an active limit or contact, an elliptic cone contact's rows in its bottom
// zone) is D_i (aref_i - J_i a) (D_i: efc_D, aref_i: its reference
// acceleration, from the state at the step's start): the step takes such a
// constraint on the trees it solves as a RigidConstraint (coupled_step.h),
// in place of its solved force, unilateral but for an equality, and in the
// state MuJoCo's solution at the step's start (with the last step's forces
// of ours) has it in (RigidConstraint::start_residual): a satisfied row
// released, taken back where the step's solution has it push (where this
// step's forces of ours press a body onto a contact that last step's left
// idle); an elliptic cone contact in its zone, its force linearized about
// MuJoCo's solution in the middle zone (sliding); a friction loss row in
// its state (quadratic, or its constant force either way). A constraint
// between a solved tree and one the step does not solve (a box resting on
// another) is taken with that one held still: J on the solved tree's
// degrees of freedom alone. Rows on three trees or more keep the force
// MuJoCo solved for them.
void World::LinearizeConstraints(double dt) {
  const mjModel* m = model_;
  const mjData* d = data_;
  const MjJacobianRows constraint_jacobian = {d->efc_J, d->efc_J_rownnz, d->efc_J_rowadr,
                                              d->efc_J_colind};
  // (ScaleForDamping's, kept from step to step)
  if (damping_factors_.size() < rigid_.trees.size()) damping_factors_.resize(rigid_.trees.size());
  for (DampingFactors& tree_factors : damping_factors_) tree_factors.factored = false;
  for (int first = 0, rows = 1; first < d->nefc; first += rows) {
    rows = ConstraintRows(first);
    const int type = d->efc_type[first];
    // the constraint's trees that the step solves (one or two), their
    // slots in rigid_ and their first degrees of freedom in MuJoCo's
    std::array<int, 2> slots = {-1, -1}, first_dofs = {0, 0};
    int num_solved = 0, num_columns = 0;
    for (const int root : row_trees_[static_cast<size_t>(first)]) {
      if (root < 0 || tree_slot_[root] < 0) continue;
      slots[num_solved] = tree_slot_[root];
      first_dofs[num_solved++] = tree_first_dof_[root];
      num_columns += tree_num_dofs_[root];
    }
    if (num_solved == 0) continue;
    RigidConstraint& constraint = rigid_.AddConstraint();
    constraint.trees = slots;
    constraint.jacobian.setZero(rows, num_columns);
    for (int r = 0; r < rows; ++r) {
      const int i = first + r;
      int column = 0;
      for (int k = 0; k < num_solved; ++k) {
        RigidTree& tree = rigid_.trees[static_cast<size_t>(slots[k])];
        const int size = static_cast<int>(tree.velocity.size());
        auto row = constraint.jacobian.row(r).segment(column, size);
        JacobianRowSegment(m, constraint_jacobian, i, first_dofs[k], row);
        tree.impulse -= dt * d->efc_force[i] * row.transpose();
        column += size;
      }
    }
    constraint.mass = Eigen::Map<const ConstraintVector>(d->efc_D + first, rows);
    constraint.reference = Eigen::Map<const ConstraintVector>(d->efc_aref + first, rows);
    if (type == mjCNSTR_EQUALITY) {
      constraint.kind = RigidConstraint::Kind::kEquality;
    } else if (type == mjCNSTR_CONTACT_ELLIPTIC) {
      constraint.kind = RigidConstraint::Kind::kEllipticCone;
      const mjContact& contact = d->contact[d->efc_id[first]];
      constraint.cone = ConstraintVector::NullaryExpr(
          rows, [&](Eigen::Index r) { return r == 0 ? contact.mu : contact.friction[r - 1]; });
    } else if (type == mjCNSTR_FRICTION_DOF || type == mjCNSTR_FRICTION_TENDON) {
      constraint.kind = RigidConstraint::Kind::kFrictionLoss;
      constraint.friction_loss = d->efc_frictionloss[first];
    } else {
      constraint.kind = RigidConstraint::Kind::kUnilateral;
    }
    if (type != mjCNSTR_EQUALITY) {
      constraint.start_residual =
          Eigen::Map<const ConstraintVector>(constraint_rates_.data() + first, rows) -
          constraint.reference;
    }
    if (tree_damped_[rigid_roots_[static_cast<size_t>(slots[0])]] ||
        (num_solved == 2 && tree_damped_[rigid_roots_[static_cast<size_t>(slots[1])]])) {
      ScaleForDamping(&constraint);
    }
  }
}

// MuJoCo solves a constraint's force from the acceleration a = M^-1 (f +
// J^T force) and then integrates with the damping implicitly: the velocity
// change u = h (M + h B)^-1 M a, so J a = J M^-1 (M + h B) u / h, not the
// J u / h the step's law takes (RigidConstraint). The step takes J a as
// tau J u / h, tau the ratio of the constraint's J M^-1 J^T to its J (M +
// h B)^-1 J^T (traces over its rows): exact for a constraint's own
// response, and for any on a tree of one degree of freedom. Multiplied into
// the law, tau would make it non-symmetric; the constraint is given
// instead rows sqrt(tau) J, references aref / sqrt(tau), and so forces (its
// friction loss, its start residual) divided by sqrt(tau), which is the same
// law on the same J^T force (the laws' forces are of degree one in J a -
// aref, the cone's zones of degree zero), and symmetric.
void World::ScaleForDamping(RigidConstraint* constraint) {
  double undamped = 0.0, damped = 0.0;  // tr(J M^-1 J^T), tr(J (M + h B)^-1 J^T)
  int column = 0;
  for (const int slot : constraint->trees) {
    if (slot < 0) continue;
    const int root = rigid_roots_[static_cast<size_t>(slot)];
    const int size = tree_num_dofs_[root];
    DampingFactors& tree_factors = damping_factors_[static_cast<size_t>(slot)];
    if (!tree_factors.factored) {  // (the tree's first constraint)
      MassBlock(root, &mass_block_);
      tree_factors.undamped.compute(mass_block_);
      tree_factors.damped.compute(rigid_.trees[static_cast<size_t>(slot)].mass);
      tree_factors.factored = true;
    }
    // (row by row, J_r M^-1 J_r^T, into a kept vector: whole products
    // of the rows would go to temporaries on the heap)
    if (damping_solution_.size() < static_cast<size_t>(size)) damping_solution_.resize(size);
    Eigen::Map<Eigen::VectorXd> solution(damping_solution_.data(), size);
    for (Eigen::Index r = 0; r < constraint->jacobian.rows(); ++r) {
      const auto row = constraint->jacobian.row(r).segment(column, size);
      solution = tree_factors.undamped.solve(row.transpose());
      undamped += row.dot(solution);
      solution = tree_factors.damped.solve(row.transpose());
      damped += row.dot(solution);
    }
    column += size;
  }
  if (!(damped > 0.0)) return;
  const double root_tau = std::sqrt(undamped / damped);
  constraint->jacobian *= root_tau;
  constraint->reference /= root_tau;
  constraint->friction_loss /= root_tau;
  if (constraint->start_residual.size() > 0) constraint->start_residual /= root_tau;
}

// The tree's block of MuJoCo's sparse qM, which holds, in row i, M(i, i),
// then M(i, j) for j = i's parent DoF, its parent, ...
void World::MassBlock(int root, Eigen::MatrixXd* mass) const {
  const mjModel* m = model_;
  const int first = tree_first_dof_[root];
  const int size = tree_num_dofs_[root];
  mass->setZero(size, size);
  for (int i = first; i < first + size; ++i) {
    int address = m->dof_Madr[i];
    for (int j = i; j >= 0; j = m->dof_parentid[j]) {
      (*mass)(i - first, j - first) = (*mass)(j - first, i - first) = data_->qM[address++];
    }
  }
}

// MuJoCo's Euler step (and its implicit one) integrates a tree's velocities
// v with its joints' damping B implicitly: (M + h B) (v' - v) = h f, f the
// forces with the damping's -B v at the step's start (h: the time step).
// Its implicit step takes so the actuators' forces' rates with their
// velocities too (a velocity servo's -kv): - h sum_a r_a m_a m_a^T, m_a
// the actuator's moment arms, r_a its rate (taken where < 0, as a
// damping); and the tendons' damping, h sum_t b_t J_t^T J_t. The substeps
// take h, not their own, so that (their mean force being MuJoCo's) the
// velocities they reach are the ones MuJoCo's step reaches.
void World::TreeMass(int root, Eigen::MatrixXd* mass_out) {
  const mjModel* m = model_;
  const int first = tree_first_dof_[root];
  const int size = tree_num_dofs_[root];
  MassBlock(root, mass_out);
  Eigen::MatrixXd& mass = *mass_out;
  // scale times the velocity terms MuJoCo takes with the joints' damping
  // (damps_velocity_terms_): the actuators' rates, where < 0, and the tendons'
  // damping, into `target`
  auto add_rates = [&](Eigen::MatrixXd& target, double scale) {
    for (int a = 0; a < m->nu; ++a) {
      const double rate = ActuatorForceRate(a);
      if (!(rate < 0.0)) continue;
      const Eigen::Map<const Eigen::VectorXd> arms(data_->actuator_moment + a * m->nv + first,
                                                   size);
      target.noalias() -= scale * rate * arms * arms.transpose();
    }
    const MjJacobianRows tendon_jacobian = {data_->ten_J, data_->ten_J_rownnz, data_->ten_J_rowadr,
                                            data_->ten_J_colind};
    if (tendon_arms_.size() < static_cast<size_t>(size)) tendon_arms_.resize(size);
    Eigen::Map<Eigen::RowVectorXd> arms(tendon_arms_.data(), size);
    for (int t = 0; t < m->ntendon; ++t) {
      if (!(m->tendon_damping[t] > 0.0)) continue;
      JacobianRowSegment(m, tendon_jacobian, t, first, arms);
      target.noalias() += scale * m->tendon_damping[t] * arms.transpose() * arms;
    }
  };
  if (m->opt.integrator == mjINT_RK4) {
    // RK4 on M v' = f - B v, f held through its stages (B: the joints'
    // damping and the velocity terms above): v+ - v = h P(X) M^-1 (f - B
    // v), X = -h M^-1 B, P(z) = 1 + z / 2 + z^2 / 6 + z^3 / 24, so the
    // step's matrix is (P(X) M^-1)^-1 (symmetric: each term (M^-1 B)^k
    // M^-1 is), positive definite exactly where RK4 is stable for B (P's
    // root, 2.785, is RK4's bound). (In kept matrices: a warm step
    // allocates nothing.)
    Eigen::MatrixXd& damping = rk4_damping_;
    damping.setZero(size, size);
    damping.diagonal() = Eigen::Map<const Eigen::VectorXd>(m->dof_damping + first, size);
    if (damps_velocity_terms_) add_rates(damping, 1.0);
    if (damping.isZero(0.0)) return;
    rk4_factor_.compute(mass);
    Eigen::MatrixXd& inverse = rk4_inverse_;
    Eigen::MatrixXd& x = rk4_x_;
    Eigen::MatrixXd& product = rk4_product_;
    Eigen::MatrixXd& p = rk4_p_;
    inverse.setIdentity(size, size);
    rk4_factor_.solveInPlace(inverse);
    x.noalias() = -m->opt.timestep * inverse * damping;
    // P(X) = I + X (I / 2 + X (I / 6 + X / 24)), by Horner
    p = x / 24.0;
    p.diagonal().array() += 1.0 / 6.0;
    product.noalias() = x * p;
    product.diagonal().array() += 0.5;
    p.noalias() = x * product;
    p.diagonal().array() += 1.0;
    product.noalias() = p * inverse;
    mass = 0.5 * (product + product.transpose());
    rk4_factor_.compute(mass);
    mass.setIdentity();
    rk4_factor_.solveInPlace(mass);
    return;
  }
  for (int i = 0; i < size; ++i) mass(i, i) += m->opt.timestep * m->dof_damping[first + i];
  if (damps_velocity_terms_) add_rates(mass, m->opt.timestep);
}

// d force / d velocity of actuator a, as MuJoCo's implicit step takes it:
// its affine bias's velocity term, and its affine gain's times the input:
// the actuator's activation, or its control as given (MuJoCo 2.2.2's rate
// takes it unclamped, though the force takes it clamped to its range: with
// a control of 0.8 beyond a range up to 0.5, the clamped one left the
// prediction 0.3 rad/s off)
double World::ActuatorForceRate(int a) const {
  const mjModel* m = model_;
  double rate = 0.0;
  if (m->actuator_biastype[a] == mjBIAS_AFFINE) rate += m->actuator_biasprm[mjNBIAS * a + 2];
  if (m->actuator_gaintype[a] == mjGAIN_AFFINE) {
    const double input =
        m->actuator_dyntype[a] == mjDYN_NONE ? data_->ctrl[a] : data_->act[a - (m->nu - m->na)];
    rate += m->actuator_gainprm[mjNGAIN * a + 2] * input;
  }
  return rate;
}

// Between substeps, the trees this substep did not solve move on under the
// forces besides ours, (M + h B)^-1 (once a step: MuJoCo's M is that of the
// step's start, as is its own step's), so that a tree solved in a later
// substep starts where MuJoCo, stepped once with the substeps' mean force,
// will have it.
void World::AdvanceUnsolvedTrees(double dt) {
  const mjModel* m = model_;
  FindOtherForces();
  if (!free_acceleration_ready_) {
    free_acceleration_.resize(m->nv);
    mj_solveM(m, data_, free_acceleration_.data(), other_forces_.data(), 1);
    for (int root = 1; root < m->nbody; ++root) {
      if (!tree_damped_[root] || m->body_rootid[root] != root) continue;
      const int first = tree_first_dof_[root];
      const int size = tree_num_dofs_[root];
      TreeMass(root, &mass_block_);
      mass_factor_.compute(mass_block_);
      Eigen::Map<Eigen::VectorXd>(free_acceleration_.data() + first, size) =
          mass_factor_.solve(Eigen::Map<const Eigen::VectorXd>(other_forces_.data() + first, size));
    }
    free_acceleration_ready_ = true;
  }
  for (int root = 1; root < m->nbody; ++root) {
    if (m->body_rootid[root] != root || tree_num_dofs_[root] == 0 || tree_slot_[root] >= 0) {
      continue;
    }
    for (int i = tree_first_dof_[root]; i < tree_first_dof_[root] + tree_num_dofs_[root]; ++i) {
      substep_velocity_[i] += dt * free_acceleration_[i];
    }
    tree_carried_[root] = 1;
  }
}

// The trees of the MuJoCo bodies in contact this substep, and each contact's
// point on its body, for the coupled step to solve with the deformables
// (coupled_step.h, RigidSystem): the tree's block of MuJoCo's mass matrix,
// its velocities, and dt times the generalized forces that act on it
// besides the contacts: gravity and bias, passive forces, actuators, the
// user's applied forces, and MuJoCo's constraint forces of the last step
// (mj_step2 finds this step's after; the last step's keep a box that a
// floor holds up, under a body resting on it, at rest in the prediction).
void World::BuildRigidSystem(double dt) {
  const mjModel* m = model_;
  mjData* d = data_;
  for (size_t t = 0; t < rigid_.trees.size(); ++t) tree_slot_[rigid_roots_[t]] = -1;
  rigid_roots_.clear();
  rigid_.Clear();
  if (!scene_.solver.implicit_rigid) return;
  // the point p_W of `body` (whose tree has degrees of freedom) in the
  // system, its tree added first if it is not yet
  auto add_point = [&](int body, const Eigen::Vector3d& p_W) -> RigidPoint& {
    const int root = m->body_rootid[body];
    const int first = tree_first_dof_[root];
    const int size = tree_num_dofs_[root];
    FindOtherForces();
    if (tree_slot_[root] < 0) {
      tree_slot_[root] = static_cast<int>(rigid_.trees.size());
      rigid_roots_.push_back(root);
      RigidTree& tree = rigid_.AddTree();
      TreeMass(root, &tree.mass);
      tree.velocity = Eigen::Map<const Eigen::VectorXd>(substep_velocity_.data() + first, size);
      tree.impulse = dt * Eigen::Map<const Eigen::VectorXd>(other_forces_.data() + first, size);
    }
    jacobian_.resize(3 * static_cast<size_t>(m->nv));
    mj_jac(m, d, jacobian_.data(), nullptr, p_W.data(), body);
    RigidPoint& rigid_point = rigid_.AddPoint();
    rigid_point.tree = tree_slot_[root];
    rigid_point.jacobian =
        Eigen::Map<const MjJacobian>(jacobian_.data(), 3, m->nv).middleCols(first, size);
    return rigid_point;
  };
  size_t point = 0;
  for (size_t c = 0; c < contacts_.size(); ++c) {
    const int body = contact_rigid_body_[c];
    if (body < 0) continue;
    const Eigen::Vector3d& p_W = reaction_points_[point++];
    const int root = m->body_rootid[body];
    // (welded to the world, or moved by mocap: its velocity is known)
    if (tree_num_dofs_[root] == 0) continue;
    const RigidPoint& rigid_point = add_point(body, p_W);
    contacts_[c].rigid_point = static_cast<int>(rigid_.points.size()) - 1;
    if (tree_carried_[root]) {  // the point's velocity from the tree's carried one
      const Eigen::Vector3d v =
          rigid_point.jacobian * rigid_.trees[static_cast<size_t>(rigid_point.tree)].velocity;
      (contacts_[c].body_a < 0 ? contacts_[c].velocity_a : contacts_[c].velocity_b) = v;
    }
  }
  // attachments: their pins carried by their body's tree (RigidPin), at
  // the reaction points that follow the contacts' (KeepReactionPoints)
  for (size_t i = 0; i < bodies_.size(); ++i) {
    const size_t num_pins = bodies_[i]->pinned_vertices().size();
    for (size_t k = 0; k < num_pins; ++k) {
      const int body = PinBody(i, k);
      if (body < 0) continue;
      if (tree_num_dofs_[m->body_rootid[body]] == 0) {  // (a body that does not move)
        ++point;
        continue;
      }
      add_point(body, reaction_points_[point++]);
      rigid_.pins.push_back(
          {static_cast<int>(i), static_cast<int>(k), static_cast<int>(rigid_.points.size()) - 1});
    }
  }
  // (once every tree is in, each added after FindOtherForces: a constraint
  // to a tree not solved holds it still)
  if (LinearizedConstraints() && !rigid_.trees.empty()) LinearizeConstraints(dt);
}

std::vector<World::GeomSummary> World::GeomsMetByShape() const {
  std::vector<GeomSummary> summaries;
  for (const auto& [g, shape] : geom_shapes_) {
    std::string kind;
    switch (shape.type) {
      case mjGEOM_PLANE:
        kind = "plane";
        break;
      case mjGEOM_SPHERE:
        kind = "sphere";
        break;
      case mjGEOM_CAPSULE:
        kind = "capsule";
        break;
      case mjGEOM_ELLIPSOID:
        kind = "ellipsoid";
        break;
      case mjGEOM_CYLINDER:
        kind = "cylinder";
        break;
      case mjGEOM_BOX:
        kind = "box";
        break;
      case mjGEOM_MESH:
        kind = "mesh: convex hull of " + std::to_string(shape.plane_normal.size()) + " planes";
        break;
      case mjGEOM_HFIELD:
        kind = "height field " + std::to_string(shape.rows) + " x " + std::to_string(shape.cols);
        break;
      default:
        kind = "type " + std::to_string(shape.type) + " (not met)";
        break;
    }
    summaries.push_back({GeomLabel(model_, g), kind});
  }
  return summaries;
}

int World::PinBody(size_t deformable, size_t pin) const {
  const int frame = bodies_[deformable]->pin_frame(pin);
  return frame >= 0 ? attach_bodies_[deformable][static_cast<size_t>(frame)] : -1;
}

Eigen::Isometry3d World::SubstepPose(int body) const {
  return substep_moved_[body] ? substep_pose_[body] : BodyPose(data_, body);
}

Eigen::Vector3d World::AtStepStart(int body, const Eigen::Vector3d& p) const {
  if (body <= 0 || !substep_moved_[body]) return p;
  return BodyPose(data_, body) * (substep_pose_[body].inverse() * p);
}

void World::SubstepTwist(int body, Eigen::Vector3d& omega, Eigen::Vector3d& v) {
  const mjModel* m = model_;
  if (!tree_carried_[m->body_rootid[body]]) {  // MuJoCo's velocity
    double velocity[6];                        // angular, then linear at the body origin xpos
    mj_objectVelocity(m, data_, mjOBJ_XBODY, body, velocity, 0);
    omega = Eigen::Vector3d(velocity[0], velocity[1], velocity[2]);
    v = Eigen::Vector3d(velocity[3], velocity[4], velocity[5]);
    return;
  }
  // the tree's velocities as the substeps predicted them, through the
  // Jacobians of the body's origin
  jacobian_.resize(3 * static_cast<size_t>(m->nv));
  rotation_jacobian_.resize(3 * static_cast<size_t>(m->nv));
  mj_jacBody(m, data_, jacobian_.data(), rotation_jacobian_.data(), body);
  const Eigen::Map<const Eigen::VectorXd> qvel(substep_velocity_.data(), m->nv);
  v = Eigen::Map<const MjJacobian>(jacobian_.data(), 3, m->nv) * qvel;
  omega = Eigen::Map<const MjJacobian>(rotation_jacobian_.data(), 3, m->nv) * qvel;
}

void World::AdvanceSubstepPoses(double dt) {
  for (int b = 1; b < model_->nbody; ++b) {
    if (model_->body_weldid[b] == 0) continue;  // (no velocity: fixed, or moved by mocap)
    Eigen::Vector3d omega, v;
    SubstepTwist(b, omega, v);
    substep_pose_[b] = Advance(SubstepPose(b), omega, v, dt);
    substep_moved_[b] = 1;
  }
}

// MuJoCo moves a tree by dt times its velocity at the step's end; the
// substeps moved it (the poses the deformables touched) by dt / substeps
// times each substep's. A tree some substep solved is moved on by the
// difference, so that it ends where the substeps left it (plus what
// MuJoCo's own constraints changed its velocity by, over the whole step);
// left where MuJoCo put it, a body pressed into a stiff deformable at a
// pose the deformable never saw was pushed back the next step, which kept
// a light arm rocking. A tree no substep solved keeps MuJoCo's position.
void World::FollowSubstepPaths() {
  const mjModel* m = model_;
  mjData* d = data_;
  if (std::none_of(tree_solved_.begin(), tree_solved_.end(), [](char c) { return c != 0; })) {
    return;
  }
  for (int root = 1; root < m->nbody; ++root) {
    for (int i = tree_first_dof_[root]; i < tree_first_dof_[root] + tree_num_dofs_[root]; ++i) {
      substep_path_[i] =
          tree_solved_[root] ? substep_path_[i] - m->opt.timestep * substep_velocity_[i] : 0.0;
    }
  }
  // mj_integratePos renormalizes every quaternion, also where it adds
  // nothing: the joints of the other trees get their positions back
  kept_qpos_.assign(d->qpos, d->qpos + m->nq);
  mj_integratePos(m, d->qpos, substep_path_.data(), 1.0);
  for (int j = 0; j < m->njnt; ++j) {
    if (tree_solved_[m->body_rootid[m->jnt_bodyid[j]]]) continue;
    const int size = m->jnt_type[j] == mjJNT_FREE ? 7 : m->jnt_type[j] == mjJNT_BALL ? 4 : 1;
    std::copy_n(kept_qpos_.data() + m->jnt_qposadr[j], size, d->qpos + m->jnt_qposadr[j]);
  }
}

// mj_step2, which integrates with Euler (or implicitly): mj_step's second
// part. For RK4, mj_step2 would integrate with Euler too (MuJoCo 2.2.2), so
// the rest of what mj_step does after mj_step1's part is done here, as
// mj_step does it, then mj_RungeKutta, which holds xfrc_applied (the
// deformables' forces) through its four stages. Without forces of ours the
// result is mj_step's, to rounding (tests/mujoco_bridge/world_test.cc).
void World::StepMuJoCoSecondPart() {
  const mjModel* m = model_;
  mjData* d = data_;
  if (m->opt.integrator != mjINT_RK4) {
    mj_step2(m, d);
    return;
  }
  mj_fwdActuation(m, d);
  mj_fwdAcceleration(m, d);
  mj_fwdConstraint(m, d);
  mj_sensorAcc(m, d);
  mj_checkAcc(m, d);
  if (mjENABLED(mjENBL_FWDINV)) mj_compareFwdInv(m, d);
  mj_RungeKutta(m, d, 4);
}

// force at a world point -> force and torque about the centre of mass xipos
void World::AddRigidForce(int body, const Eigen::Vector3d& point, const Eigen::Vector3d& force) {
  if (body <= 0) return;  // the world body does not move
  Eigen::Vector3d arm = point - Eigen::Map<const Eigen::Vector3d>(data_->xipos + 3 * body);
  Eigen::Map<Eigen::Vector3d>(accumulated_.data() + 6 * body) += force;                 // force
  Eigen::Map<Eigen::Vector3d>(accumulated_.data() + 6 * body + 3) += arm.cross(force);  // torque
}

void World::UpdateProxies() {
  for (auto& proxy : proxies_) {
    const Eigen::Isometry3d X_WB = SubstepPose(proxy->body);
    const Eigen::Matrix3d R_WB = X_WB.linear();
    const Eigen::Vector3d p_WB = X_WB.translation();
    // (a body that has not moved, bit for bit, such as a static one: its
    // positions are still right, and the penetration solver keeps what it
    // derived from them, see BuildCollisionObjects)
    RigidFrame& frame = proxy->frame;
    if (proxy->placements > 0 && SameBits({R_WB.data(), 9}, {frame.rotation.data(), 9}) &&
        SameBits({p_WB.data(), 3}, {frame.translation.data(), 3})) {
      continue;
    }
    // (the box of the positions as they are written: the solver then need
    // not pass over them again for it)
    const Positions& rest = proxy->mesh->positions();
    PositionBounds bounds;
    for (Eigen::Index v = 0; v < rest.rows(); ++v) {
      const Eigen::Vector3d p_W = X_WB * rest.row(v).transpose();
      proxy->positions.row(v) = p_W.transpose();
      bounds.Add(p_W);
    }
    frame.rotation = R_WB;
    frame.translation = p_WB;
    frame.bounds = bounds;
    proxy->placements = std::min(proxy->placements + 1, 2);
  }
}

int World::ForEachGeomPenetration(
    bool consistent,
    const std::function<void(int, int, int, double, const Eigen::Vector3d&)>& visit) {
  const mjModel* m = model_;
  int fallback = 0;
  // each deformable's box: a geom that cannot reach it is passed over
  // whole (a robot's many geoms, most far from any deformable, cost a test
  // each instead of one per vertex)
  std::vector<Eigen::Vector3d>& box_lo = geom_box_lo_;
  std::vector<Eigen::Vector3d>& box_hi = geom_box_hi_;
  box_lo.resize(bodies_.size());
  box_hi.resize(bodies_.size());
  for (size_t i = 0; i < bodies_.size(); ++i) {
    const Positions& x = bodies_[i]->positions();
    box_lo[i] = x.colwise().minCoeff().transpose();
    box_hi[i] = x.colwise().maxCoeff().transpose();
  }
  for (const auto& [g, shape] : geom_shapes_) {
    Eigen::Vector3d x_g = Eigen::Map<const Eigen::Vector3d>(data_->geom_xpos + 3 * g);
    Eigen::Matrix3d R_g = Eigen::Map<const MjRotation>(data_->geom_xmat + 9 * g);
    const int body = m->geom_bodyid[g];
    if (substep_moved_[body]) {  // (where a substep put its body)
      const Eigen::Isometry3d moved = substep_pose_[body] * BodyPose(data_, body).inverse();
      x_g = moved * x_g;
      R_g = moved.linear() * R_g;
    }
    // stage 2 of the consistent method: where an edge enters the geom (one
    // pointer captured: std::function keeps it without allocating)
    struct Placed {
      const GeomShape& shape;
      const Eigen::Vector3d& x_g;
      const Eigen::Matrix3d& R_g;
    } placed{shape, x_g, R_g};
    const ShapeCrossing crossing = [&placed](const Eigen::Vector3d& outside,
                                             const Eigen::Vector3d& inside, Eigen::Vector3d& at,
                                             Eigen::Vector3d& normal) {
      const Eigen::Vector3d o = placed.R_g.transpose() * (outside - placed.x_g);
      const Eigen::Vector3d in = placed.R_g.transpose() * (inside - placed.x_g);
      double t = 0.0;
      if (!GeomEntry(placed.shape, o, in, t, normal)) return false;
      at = placed.x_g + placed.R_g * (o + t * (in - o));
      normal = placed.R_g * normal;
      return true;
    };
    // (MuJoCo 2.2.2 gives planes and height fields no bounding radius)
    const bool bounded = shape.type != mjGEOM_PLANE && shape.type != mjGEOM_HFIELD;
    const double reach = bounded ? m->geom_rbound[g] : HeightFieldRadius(shape);
    for (size_t i = 0; i < bodies_.size(); ++i) {
      const Eigen::Vector3d centre = 0.5 * (box_lo[i] + box_hi[i]);
      const Eigen::Vector3d half = 0.5 * (box_hi[i] - box_lo[i]);
      if (shape.type == mjGEOM_PLANE) {
        // the box's lowest point over the plane (its normal: the geom's z)
        const Eigen::Vector3d n = R_g.col(2);
        if (n.dot(centre - x_g) - n.cwiseAbs().dot(half) > kGeomCullMargin) continue;
      } else {
        // the box beyond the geom's bounding sphere
        const Eigen::Vector3d gap = ((box_lo[i] - x_g).cwiseMax(x_g - box_hi[i])).cwiseMax(0.0);
        if (gap.norm() > reach + kGeomCullMargin) continue;
      }
      const DeformableBody& deformable = *bodies_[i];
      std::vector<ShapePoint>& points = geom_points_;
      points.clear();
      for (int v = 0; v < deformable.num_vertices(); ++v) {
        Eigen::Vector3d p = deformable.positions().row(v).transpose();
        if (bounded && (p - x_g).norm() > m->geom_rbound[g]) continue;
        ShapePoint point;
        point.vertex = v;
        if (!GeomPenetration(shape, R_g.transpose() * (p - x_g), point.depth, point.direction)) {
          continue;
        }
        point.direction = R_g * point.direction;
        points.push_back(point);
      }
      // The consistent method's depths where it differs from the signed
      // distance: not on a plane (every crossing lies in it, so both give
      // the distance below it) nor a height field (pushed up only)
      if (consistent && shape.type != mjGEOM_PLANE && shape.type != mjGEOM_HFIELD) {
        geom_depth_.Solve(deformable.mesh(), deformable.positions(), points, crossing);
        for (const ShapePoint& point : points) fallback += point.source == DepthSource::kFallback;
      }
      for (const ShapePoint& point : points) {
        visit(static_cast<int>(i), point.vertex, g, point.depth, point.direction);
      }
    }
  }
  return fallback;
}

void World::AddGeomContacts(double dt) {
  const mjModel* m = model_;
  const bool consistent = solver_.options().method == DepthMethod::kConsistent;
  auto add = [&](int i, int v, int g, double depth, const Eigen::Vector3d& direction) {
    const int body = m->geom_bodyid[g];
    const DeformableBody& deformable = *bodies_[i];
    Eigen::Vector3d p = deformable.positions().row(v).transpose();
    ContactPoint contact;
    contact.body_a = i;
    contact.vertex_a = v;
    const PointMotion motion = RigidPointMotion(body, p, dt);
    contact.velocity_b = motion.velocity;
    contact.arc = -motion.arc;
    contact.mass_b = body > 0 ? m->body_mass[body] : 0.0;
    contact.depth = depth;
    contact.direction = direction;
    contact.stiffness =
        kappa_[i] * ContactAreaOf(contact_area_, deformable.model().mesh(), deformable.positions(),
                                  v, direction, deformable.model().contact_areas()[v]);
    contact.friction = std::max(friction_[i], m->geom_friction[3 * g]);  // MuJoCo combines by max
    contact.damping_ratio = damping_[i];
    contacts_.push_back(contact);
    contact_rigid_body_.push_back(body);
    contact_key_.push_back({i, v, -1 - g});
  };
  // (by reference: a std::function holding the lambda itself would put it on the heap)
  metrics_.fallback_points += ForEachGeomPenetration(consistent, std::ref(add));
}

// A friction spring is the displacement of A's point from where it stuck on
// B, so it turns with B's material there: a pair that turns together about
// the contact's normal (a block carried round on a turntable) keeps its
// springs as they were against both. Kept in world axes, the springs of a
// turning pair lagged by the angle turned: a soft block on a table turning
// at 1 rad/s crept 0.18 mm in a second (tests/scenarios/friction_test.cc).
Eigen::Quaterniond World::PenetratedFrame(size_t c) const {
  const ContactPoint& contact = contacts_[c];
  if (contact.body_b >= 0) return bodies_[contact.body_b]->ElementRotation(contact.tet_b);
  // (B rigid: A is a deformable's vertex, the rigid body B's)
  const int body = contact_rigid_body_[c];
  if (body <= 0) return Eigen::Quaterniond::Identity();
  return Eigen::Quaterniond(SubstepPose(body).linear());
}

void World::RestoreFrictionSprings() {
  AssignWithRoom(contact_frame_, contacts_.size(), Eigen::Quaterniond::Identity());
  if (!contact_settings_.stick) return;
  for (size_t c = 0; c < contacts_.size(); ++c) {
    if (contacts_[c].friction > 0.0) contact_frame_[c] = PenetratedFrame(c);
    auto it = std::lower_bound(springs_.begin(), springs_.end(), contact_key_[c],
                               [](const std::pair<ContactKey, Eigen::Vector3d>& a,
                                  const ContactKey& b) { return a.first < b; });
    if (it == springs_.end() || it->first != contact_key_[c]) continue;
    // (turned with B into world axes, then onto this step's tangent plane,
    // its length kept: the spring's force turns with the contact's direction)
    const Eigen::Vector3d kept = contact_frame_[c] * it->second;
    const Eigen::Vector3d s = Tangential(kept, contacts_[c].direction);
    const double length = s.norm();
    if (length > 0.0) contacts_[c].stick = (kept.norm() / length) * s;
  }
}

void World::KeepFrictionSprings() {
  springs_.clear();
  for (size_t c = 0; c < contacts_.size(); ++c) {
    if (contacts_[c].stick != Eigen::Vector3d::Zero()) {
      springs_.emplace_back(contact_key_[c], contact_frame_[c].inverse() * contacts_[c].stick);
    }
  }
  std::sort(springs_.begin(), springs_.end(),
            [](const auto& a, const auto& b) { return a.first < b.first; });
}

void World::BuildCollisionObjects() {
  objects_.clear();
  for (size_t i = 0; i < bodies_.size(); ++i) {
    objects_.push_back(
        {&bodies_[i]->mesh(), &bodies_[i]->positions(), false, scene_.tetbodies[i].self_collide});
  }
  // a proxy placed once and never moved (a static body's) is fixed for
  // every solver: its positions are those of any earlier solve; one that
  // moves, moves rigidly with its body's frame (its mesh is in the body
  // frame)
  for (const auto& proxy : proxies_) {
    const bool fixed = proxy->placements == 1;
    objects_.push_back({proxy->mesh.get(), &proxy->positions, true, false, fixed,
                        fixed ? nullptr : &proxy->frame});
  }
}

int World::ProxyBody(int proxy) const {
  return proxies_[proxy]->body;
}

int World::MetricObject(int collision_object) const {
  const int num_deformables = static_cast<int>(bodies_.size());
  if (collision_object < num_deformables) return collision_object;
  return num_deformables + proxies_[collision_object - num_deformables]->body;
}

std::vector<Interpenetration> World::MeasureInterpenetration() {
  UpdateProxies();
  BuildCollisionObjects();
  std::vector<Interpenetration> points;
  for (const PenetrationResult& r : exact_solver_.Solve(objects_)) {
    points.push_back({MetricObject(r.object), MetricObject(r.penetrated), r.depth,
                      objects_[r.object].positions->row(r.vertex).transpose()});
  }
  const int num_deformables = static_cast<int>(bodies_.size());
  ForEachGeomPenetration(false, [&](int i, int v, int g, double depth, const Eigen::Vector3d&) {
    points.push_back({i, num_deformables + model_->geom_bodyid[g], depth,
                      bodies_[i]->positions().row(v).transpose()});
  });
  return points;
}

Eigen::Vector3d World::RigidBodyCenterOfMass(int body) const {
  return Eigen::Map<const Eigen::Vector3d>(data_->xipos + 3 * body);
}

std::vector<World::MuJoCoWarning> World::MuJoCoWarnings() const {
  const mjModel* m = model_;
  std::vector<MuJoCoWarning> warnings;
  auto add = [&](int kind, const std::string& what) {
    const int count = data_->warning[kind].number;
    const bool dropped = kind == mjWARN_CONTACTFULL || kind == mjWARN_CNSTRFULL;
    if (count > 0) warnings.push_back({what, count, dropped});
  };
  add(mjWARN_INERTIA,
      "a body's inertia matrix was (nearly) singular: give the bodies mass and inertia "
      "(<inertial>, or geoms with density)");
  add(mjWARN_CONTACTFULL,
      "MuJoCo's contact buffer was full and contacts were dropped: raise "
      "<size nconmax> (it is " +
          std::to_string(m->nconmax) + ")");
  add(mjWARN_CNSTRFULL,
      "MuJoCo's constraint buffer was full and constraints were dropped: "
      "raise <size njmax> (it is " +
          std::to_string(m->njmax) + ")");
  add(mjWARN_VGEOMFULL, "the renderer's buffer of geoms was full and some were not drawn");
  add(mjWARN_BADCTRL, "a control (ctrl) was not finite, and MuJoCo set it to 0");
  return warnings;
}

bool World::RigidBodyIsStatic(int body) const {
  const mjModel* m = model_;
  return m->body_weldid[body] == 0 && m->body_mocapid[m->body_rootid[body]] < 0;
}

void World::CollectContacts(double dt) {
  contacts_.clear();
  contact_rigid_body_.clear();
  contact_key_.clear();
  BuildCollisionObjects();
  const int num_deformables = static_cast<int>(bodies_.size());
  // a point of A inside B stands for its own contact area, but for no more
  // than B's surface area per vertex: where a coarse surface presses on a
  // finer one (a table's proxy under a small soft body), the finer samples
  // the contact, and one coarse vertex would otherwise carry the load of a
  // patch larger than the contact itself
  auto mean_surface_area = [&](int object) {
    return object < num_deformables ? mean_surface_area_[object]
                                    : proxies_[object - num_deformables]->mean_surface_area;
  };
  for (const PenetrationResult& r : solver_.Solve(objects_)) {
    ContactPoint contact;
    contact.depth = r.depth;
    contact.direction = r.direction;
    int rigid = -1;
    double area = 0.0, kappa = 0.0;
    if (r.object < num_deformables) {
      contact.body_a = r.object;
      contact.vertex_a = r.vertex;
      const DeformableBody& body = *bodies_[r.object];
      area = ContactAreaOf(contact_area_, body.model().mesh(), body.positions(), r.vertex,
                           r.direction, body.model().contact_areas()[r.vertex]);
      // (the softer body's, between two deformables: the one that gives)
      kappa = r.penetrated < num_deformables ? std::min(kappa_[r.object], kappa_[r.penetrated])
                                             : kappa_[r.object];
      contact.friction = friction_[r.object];
      contact.damping_ratio = damping_[r.object];
    } else {
      const Proxy& proxy = *proxies_[r.object - num_deformables];
      rigid = proxy.body;
      Eigen::Vector3d p = proxy.positions.row(r.vertex).transpose();
      const PointMotion motion = RigidPointMotion(proxy.body, p, dt);
      contact.velocity_a = motion.velocity;
      contact.arc = motion.arc;
      contact.mass_a = model_->body_mass[proxy.body];
      area = ContactAreaOf(contact_area_, *proxy.mesh, proxy.positions, r.vertex, r.direction,
                           proxy.areas[r.vertex]);
      kappa = kappa_[r.penetrated];
      contact.friction = std::max(friction_[r.penetrated], proxy.friction);
      contact.damping_ratio = damping_[r.penetrated];
    }
    contact.stiffness = kappa * std::min(area, mean_surface_area(r.penetrated));
    if (r.penetrated < num_deformables) {
      contact.body_b = r.penetrated;
      contact.tet_b = r.tet;
      contact.barycentric_b = r.barycentric;
    } else {
      const Proxy& proxy = *proxies_[r.penetrated - num_deformables];
      rigid = proxy.body;
      Eigen::Vector3d p = bodies_[r.object]->positions().row(r.vertex).transpose();
      const PointMotion motion = RigidPointMotion(proxy.body, p, dt);
      contact.velocity_b = motion.velocity;
      contact.arc = -motion.arc;
      contact.mass_b = model_->body_mass[proxy.body];
      contact.friction = std::max(contact.friction, proxy.friction);
    }
    contacts_.push_back(contact);
    contact_rigid_body_.push_back(rigid);
    contact_key_.push_back({r.object, r.vertex, r.penetrated});
  }
  const PenetrationStats& stats = solver_.stats();
  metrics_.penetration_ms += solver_.timings().total * 1e3;
  metrics_.penetration_points += stats.colliding;
  metrics_.kept_proxies = stats.fixed_objects + stats.framed_objects;
  metrics_.fallback_points = stats.fallback;
  metrics_.unresolved_points = stats.unresolved;
  AddGeomContacts(dt);
}

void World::Step() {
  if (!failure_.empty()) {
    metrics_ = {};
    metrics_.status = StepStatus::kFailed;
    metrics_.message = failure_;
    return;
  }
  try {
    StepOnce();
  } catch (const MuJoCoError& e) {
    // MuJoCo's state is mid-step, its stack marked in use (nothing of
    // ours is on it between calls): the world stops here
    data_->pstack = 0;
    failure_ = "MuJoCo failed step " + std::to_string(steps_) + ": " + e.what() +
               MuJoCoErrorAdvice(model_, e.what()) + "; the world steps no further";
    metrics_.status = StepStatus::kFailed;
    metrics_.message = failure_;
    try {
      RestoreStepStart();
    } catch (const MuJoCoError&) {
      // (MuJoCo failed again, finding the restored state's poses: they
      // stay as its failure left them)
    }
  }
}

void World::SaveStepStart() {
  const mjModel* m = model_;
  const mjData* d = data_;
  step_start_.time = d->time;
  step_start_.mujoco.clear();
  for (const StateArray& state : StateArrays(m)) {
    const mjtNum* values = d->*state.array;
    step_start_.mujoco.insert(step_start_.mujoco.end(), values, values + state.length);
  }
  step_start_.warnings.clear();
  for (const mjWarningStat& warning : d->warning) {
    step_start_.warnings.push_back(warning.number);
    step_start_.warnings.push_back(warning.lastinfo);
  }
  step_start_.deformables.resize(bodies_.size());
  for (size_t i = 0; i < bodies_.size(); ++i) bodies_[i]->Save(&step_start_.deformables[i]);
  step_start_.ours = ours_;
  step_start_.user = user_;
  step_start_.written = written_;
  step_start_.springs = springs_;
}

void World::RestoreStepStart(int bad_warning, int info) {
  const mjModel* m = model_;
  mjData* d = data_;
  d->time = step_start_.time;
  const double* saved = step_start_.mujoco.data();
  for (const StateArray& state : StateArrays(m)) {
    std::copy(saved, saved + state.length, d->*state.array);
    saved += state.length;
  }
  for (int k = 0; k < mjNWARNING; ++k) {
    d->warning[k].number = step_start_.warnings[2 * static_cast<size_t>(k)];
    d->warning[k].lastinfo = step_start_.warnings[2 * static_cast<size_t>(k) + 1];
  }
  if (bad_warning >= 0) {
    ++d->warning[bad_warning].number;
    d->warning[bad_warning].lastinfo = info;
  }
  for (size_t i = 0; i < bodies_.size(); ++i) bodies_[i]->Restore(step_start_.deformables[i]);
  ours_ = step_start_.ours;
  user_ = step_start_.user;
  written_ = step_start_.written;
  springs_ = step_start_.springs;
  std::fill(substep_moved_.begin(), substep_moved_.end(), 0);  // (MuJoCo's poses again)
  // the poses and velocities the world reports between steps (as a step
  // ends)
  CallMuJoCo([&] {
    mj_kinematics(m, d);
    mj_comPos(m, d);
    mj_comVel(m, d);
  });
}

void World::StepOnce() {
  Clock::time_point start = Clock::now();
  metrics_ = {};
  SaveStepStart();
  if (controller_) controller_(*this);
  mjModel* m = model_;
  mjData* d = data_;
  // MuJoCo's own instability warnings: it resets its state and goes on, so
  // count them to report a status instead of silently wrong rigid bodies.
  // Counted from 0 in the step (step_start_ keeps the counts): MuJoCo's
  // reset clears every warning before it counts the one that made it reset,
  // so a count compared with the one before the step would miss a second
  // reset.
  constexpr int kBadState[3] = {mjWARN_BADQPOS, mjWARN_BADQVEL, mjWARN_BADQACC};
  for (int k : kBadState) d->warning[k].number = 0;
  // the user's part of xfrc_applied: unchanged since we wrote user + ours,
  // the user's value as kept (exactly: (user + ours) - ours may differ from
  // user in the last bit, which would drift over many steps); changed,
  // whatever is there beyond our part
  for (int i = 0; i < 6 * m->nbody; ++i) {
    if (d->xfrc_applied[i] != written_[i]) user_[i] = d->xfrc_applied[i] - ours_[i];
  }

  Clock::time_point phase = Clock::now();
  CallMuJoCo([&] { mj_step1(m, d); });
  metrics_.mujoco_ms += MillisecondsSince(phase);

  const int substeps = std::max(1, scene_.solver.substeps);
  StepSettings settings = step_settings_;
  settings.dt = m->opt.timestep / substeps;
  std::fill(accumulated_.begin(), accumulated_.end(), 0.0);
  other_forces_ready_ = false;
  free_acceleration_ready_ = false;
  substep_velocity_.assign(d->qvel, d->qvel + m->nv);
  std::fill(tree_carried_.begin(), tree_carried_.end(), 0);
  std::fill(tree_solved_.begin(), tree_solved_.end(), 0);
  substep_path_.assign(m->nv, 0.0);
  for (int substep = 0; substep < substeps; ++substep) {
    phase = Clock::now();
    UpdateProxies();
    CollectContacts(settings.dt);
    for (size_t i = 0; i < bodies_.size(); ++i) {
      // pins follow their bodies over this substep (predicted from their velocities)
      for (size_t frame = 0; frame < attach_bodies_[i].size(); ++frame) {
        const int body = attach_bodies_[i][frame];
        Eigen::Vector3d omega, v;
        SubstepTwist(body, omega, v);
        bodies_[i]->SetPinFrame(static_cast<int>(frame),
                                Advance(SubstepPose(body), omega, v, settings.dt));
      }
    }
    metrics_.collision_ms += MillisecondsSince(phase);
    KeepReactionPoints();
    phase = Clock::now();
    BuildRigidSystem(settings.dt);  // (MuJoCo's actuation and constraint solve, its Jacobians)
    metrics_.mujoco_ms += MillisecondsSince(phase);
    phase = Clock::now();
    ContactSettings contact_settings = contact_settings_;
    RestoreFrictionSprings();
    CoupledStepReport report = StepCoupled(body_pointers_, contacts_, contact_settings, settings,
                                           &rigid_, &step_workspace_);
    KeepFrictionSprings();
    metrics_.solver_iterations += report.iterations;
    metrics_.solver_residual = std::max(metrics_.solver_residual, report.residual);
    // (CG stops at r <= tolerance * reference; the report's residual is r /
    // reference, rounded)
    if (report.residual > settings.cg_tolerance * (1.0 + 1e-9)) metrics_.solver_converged = false;
    metrics_.contact_rounds += report.rounds;
    metrics_.released_contacts += report.released_contacts;
    metrics_.stuck_contacts += report.stuck_contacts;
    metrics_.deformable_ms += MillisecondsSince(phase);
    if (report.status != StepStatus::kOk) {
      metrics_.status = report.status;
      std::ostringstream message;
      message << "tetbody '" << bodies_[report.bad_body]->name() << "' vertex " << report.bad_vertex
              << " became non-finite (its velocity, position or a force on it) at step " << steps_
              << " (t = " << d->time
              << " s); the step is undone; try a smaller timestep, more substeps or a softer "
                 "contact stiffness";
      metrics_.message = message.str();
      RestoreStepStart();
      return;
    }
    // the next substep's trees start where this one's ended (MuJoCo, stepped
    // with the substeps' mean force, then ends there too), and the bodies
    // where their velocities take them
    for (size_t t = 0; t < rigid_.trees.size(); ++t) {
      const RigidTree& tree = rigid_.trees[t];
      Eigen::Map<Eigen::VectorXd>(substep_velocity_.data() + tree_first_dof_[rigid_roots_[t]],
                                  tree.velocity_end.size()) = tree.velocity_end;
      tree_carried_[rigid_roots_[t]] = 1;
      tree_solved_[rigid_roots_[t]] = 1;
    }
    if (substeps > 1) {
      if (scene_.solver.implicit_rigid) AdvanceUnsolvedTrees(settings.dt);
      for (int i = 0; i < m->nv; ++i) substep_path_[i] += settings.dt * substep_velocity_[i];
      if (substep + 1 < substeps) AdvanceSubstepPoses(settings.dt);
    }
    // reactions on the rigid bodies, averaged over substeps, at the points
    // kept before the step
    size_t point = 0;
    for (size_t c = 0; c < contacts_.size(); ++c) {
      const int body = contact_rigid_body_[c];
      if (body < 0) continue;
      // (a proxy vertex inside a deformable, A: the proxy's body gets the force on A)
      const double sign = contacts_[c].body_a < 0 ? 1.0 : -1.0;
      AddRigidForce(body, reaction_points_[point++], sign * contacts_[c].force / substeps);
    }
    for (size_t i = 0; i < bodies_.size(); ++i) {
      const std::vector<Eigen::Vector3d>& pin_forces = bodies_[i]->pin_forces();
      for (size_t k = 0; k < pin_forces.size(); ++k) {
        const int body = PinBody(i, k);
        if (body < 0) continue;
        AddRigidForce(body, reaction_points_[point++], -pin_forces[k] / substeps);
      }
    }
    for (const ContactPoint& contact : contacts_) {
      metrics_.max_depth = std::max(metrics_.max_depth, contact.depth);
      metrics_.mean_depth += contact.depth;
    }
    metrics_.colliding_points =
        std::max(metrics_.colliding_points, static_cast<int>(contacts_.size()));
    if (!contacts_.empty()) metrics_.mean_depth /= static_cast<double>(contacts_.size());
  }
  std::fill(substep_moved_.begin(), substep_moved_.end(), 0);  // (MuJoCo's poses again)
  // xfrc_applied: the user's forces + ours (MuJoCo order: force, then torque)
  for (int b = 0; b < m->nbody; ++b) {
    for (int k = 0; k < 6; ++k) {
      // accumulated_ holds force at 0..2 and torque at 3..5, like xfrc_applied
      ours_[6 * b + k] = accumulated_[6 * b + k];
      d->xfrc_applied[6 * b + k] = user_[6 * b + k] + ours_[6 * b + k];
      written_[6 * b + k] = d->xfrc_applied[6 * b + k];
    }
  }
  phase = Clock::now();
  CallMuJoCo([&] { StepMuJoCoSecondPart(); });
  // the first of MuJoCo's bad-state warnings this step raised (its
  // reset put the bodies back at their initial state: no path to follow),
  // or -1
  int bad_state = -1;
  for (int k = 0; k < 3 && bad_state < 0; ++k) {
    if (d->warning[kBadState[k]].number > 0) bad_state = k;
  }
  int bad_index = bad_state >= 0 ? d->warning[kBadState[bad_state]].lastinfo : 0;
  if (bad_state < 0) {
    for (int k : kBadState) d->warning[k].number = step_start_.warnings[2 * static_cast<size_t>(k)];
    if (substeps > 1) FollowSubstepPaths();
  }
  // bring poses and velocities (xpos, xipos, cvel) up to the new state, so
  // that what the world reports between steps is current
  CallMuJoCo([&] {
    mj_kinematics(m, d);
    mj_comPos(m, d);
    mj_comVel(m, d);
  });
  metrics_.mujoco_ms += MillisecondsSince(phase);
  // MuJoCo checks the positions and velocities a step leaves at the start
  // of the next: checked here as MuJoCo does, so that every step done
  // leaves a state MuJoCo takes
  bool left_bad = false;
  if (bad_state < 0) {
    if (const std::optional<BadState> bad = FirstBadState(m, d)) {
      bad_state = bad->velocity ? 1 : 0;  // (kBadState's order)
      bad_index = bad->index;
      left_bad = true;
    }
  }
  if (bad_state >= 0) {
    constexpr const char* kWhat[3] = {"position qpos", "velocity qvel", "acceleration qacc"};
    metrics_.status = StepStatus::kDiverged;
    std::ostringstream message;
    message << (left_bad ? "MuJoCo's step left" : "MuJoCo found") << " a non-finite or huge "
            << kWhat[bad_state] << "[" << bad_index << "] at step " << steps_
            << "; the step is undone; try a smaller timestep or softer actuators and joints";
    metrics_.message = message.str();
    RestoreStepStart(kBadState[bad_state], bad_index);
    metrics_.total_ms = MillisecondsSince(start);
    return;
  }
  ++steps_;
  metrics_.total_ms = MillisecondsSince(start);
}

Eigen::Vector3d World::LinearMomentum() const {
  Eigen::Vector3d p = Eigen::Vector3d::Zero();
  for (const auto& body : bodies_) p += body->LinearMomentum();
  for (int b = 1; b < model_->nbody; ++b) {
    p += model_->body_mass[b] * MotionOf(model_, data_, b).velocity;
  }
  return p;
}

Eigen::Vector3d World::AngularMomentum() const {
  Eigen::Vector3d L = Eigen::Vector3d::Zero();
  for (const auto& body : bodies_) L += body->AngularMomentum();
  for (int b = 1; b < model_->nbody; ++b) {
    const BodyMotion motion = MotionOf(model_, data_, b);
    const Eigen::Vector3d p_WBcm = Eigen::Map<const Eigen::Vector3d>(data_->xipos + 3 * b);
    L += motion.spin + model_->body_mass[b] * p_WBcm.cross(motion.velocity);
  }
  return L;
}

double World::DeformableKineticEnergy() const {
  double energy = 0.0;
  for (const auto& body : bodies_) energy += body->KineticEnergy();
  return energy;
}

double World::RigidKineticEnergy() const {
  double energy = 0.0;
  for (int b = 1; b < model_->nbody; ++b) {
    const BodyMotion motion = MotionOf(model_, data_, b);
    energy += 0.5 * model_->body_mass[b] * motion.velocity.squaredNorm() +
              0.5 * motion.omega.dot(motion.spin);
  }
  return energy;
}

}  // namespace tetcosim
