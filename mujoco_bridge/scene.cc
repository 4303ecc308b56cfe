#include "mujoco_bridge/scene.h"

#include <tinyxml2.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <numbers>
#include <set>
#include <sstream>
#include <string_view>

#include "mesh/error.h"
#include "mesh/utf8.h"
#include "mesh/xml_error.h"

namespace tetcosim {
namespace {

constexpr double kSpeedOfLight = 299792458.0;  // m/s: the bound on an initial velocity

using tinyxml2::XMLElement;

class SceneParser {
 public:
  explicit SceneParser(std::string path) : path_(std::move(path)) {}

  [[noreturn]] void Fail(const XMLElement* element, const std::string& message) const {
    ThrowAt(path_, element ? element->GetLineNum() : 0,
            (element ? "<" + std::string(element->Name()) + ">: " : std::string()) + message);
  }

  void CheckAttributes(const XMLElement* element,
                       std::initializer_list<const char*> allowed) const {
    for (const tinyxml2::XMLAttribute* a = element->FirstAttribute(); a; a = a->Next()) {
      bool known = false;
      for (const char* name : allowed) known |= std::string(a->Name()) == name;
      if (!known) {
        std::string list;
        for (const char* name : allowed) list += std::string(list.empty() ? "" : ", ") + name;
        Fail(element, "unknown attribute '" + std::string(a->Name()) + "'; " +
                          (list.empty() ? "this element takes no attributes (its settings are "
                                          "child elements)"
                                        : "allowed: " + list));
      }
    }
  }

  std::vector<double> Numbers(const XMLElement* element, const char* name, size_t min_count,
                              size_t max_count) const {
    const char* text = element->Attribute(name);
    std::vector<double> values;
    if (!text) return values;
    std::istringstream in(text);
    std::string token;
    while (in >> token) {
      double value = 0.0;
      auto [end, ec] = std::from_chars(token.data(), token.data() + token.size(), value);
      if (ec != std::errc() || end != token.data() + token.size() || !std::isfinite(value)) {
        Fail(element, std::string(name) + "=\"" + text + "\" is not a list of finite numbers");
      }
      values.push_back(value);
    }
    // (an attribute written but blank is not an attribute left out: both
    // kinds of mistake, name="" and name=" ", would otherwise give defaults)
    const size_t least = std::max<size_t>(min_count, 1);
    if (values.size() < least || values.size() > max_count) {
      Fail(element, std::string(name) + " takes " + std::to_string(least) +
                        (max_count > least ? " to " + std::to_string(max_count) : "") +
                        (max_count == 1 ? " number" : " numbers") + ", got " +
                        std::to_string(values.size()) +
                        (values.empty() ? "; give a value or leave the attribute out" : ""));
    }
    return values;
  }

  std::optional<double> Number(const XMLElement* element, const char* name, double min,
                               double max) const {
    if (!element->Attribute(name)) return std::nullopt;
    double value = Numbers(element, name, 1, 1)[0];
    if (value < min || value > max) {
      std::ostringstream range;
      range << name << " = " << value << " is outside [" << min << ", " << max << "]";
      Fail(element, range.str());
    }
    return value;
  }

  // An attribute that is one of two words: whether it is `first`
  // (`fallback` where it is absent).
  bool Either(const XMLElement* element, const char* name, const char* first, const char* second,
              bool fallback) const {
    const char* text = element->Attribute(name);
    if (!text) return fallback;
    const std::string_view value(text);
    if (value == first) return true;
    if (value == second) return false;
    Fail(element, std::string(name) + " must be " + first + " or " + second);
  }

  AutoProxies AutoProxiesOf(const XMLElement* element) const {
    const char* text = element->Attribute("autoproxy");
    if (!text) return AutoProxies::kNarrowAndRound;
    const std::string_view value(text);
    if (value == "true") return AutoProxies::kNarrowAndRound;
    if (value == "narrow") return AutoProxies::kNarrow;
    if (value == "false") return AutoProxies::kNone;
    Fail(element, "autoproxy must be true, narrow or false");
  }

  bool Bool(const XMLElement* element, const char* name, bool fallback) const {
    return Either(element, name, "true", "false", fallback);
  }

  std::string File(const XMLElement* element, const char* name) const {
    const char* text = element->Attribute(name);
    if (!text) return {};
    std::filesystem::path file(text);
    if (file.is_relative()) file = std::filesystem::path(path_).parent_path() / file;
    if (!std::filesystem::exists(file)) {
      Fail(element,
           std::string(name) + " '" + text + "' does not exist (looked for " + file.string() + ")");
    }
    return file.string();
  }

  // pos, quat or euler (MJCF conventions: quat w x y z; euler x-y-z intrinsic
  // in the compiler's angle unit)
  Eigen::Isometry3d Pose(const XMLElement* element) const {
    Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
    std::vector<double> pos = Numbers(element, "pos", 3, 3);
    if (!pos.empty()) X.translation() = Eigen::Vector3d(pos[0], pos[1], pos[2]);
    std::vector<double> quat = Numbers(element, "quat", 4, 4);
    std::vector<double> euler = Numbers(element, "euler", 3, 3);
    if (!quat.empty() && !euler.empty()) Fail(element, "give quat or euler, not both");
    if (!quat.empty()) {
      Eigen::Quaterniond q(quat[0], quat[1], quat[2], quat[3]);
      if (q.norm() < 1e-12) Fail(element, "quat has zero length");
      X.linear() = q.normalized().toRotationMatrix();
    }
    if (!euler.empty()) {
      double unit = degrees_ ? std::numbers::pi / 180.0 : 1.0;
      X.linear() = (Eigen::AngleAxisd(euler[0] * unit, Eigen::Vector3d::UnitX()) *
                    Eigen::AngleAxisd(euler[1] * unit, Eigen::Vector3d::UnitY()) *
                    Eigen::AngleAxisd(euler[2] * unit, Eigen::Vector3d::UnitZ()))
                       .toRotationMatrix();
    }
    return X;
  }

  void ContactAttributes(const XMLElement* element, ContactParams& params) const {
    params.stiffness = Number(element, "stiffness", 0.0, 1e15);
    params.damping = Number(element, "damping", 0.0, 100.0);
    params.friction = Number(element, "friction", 0.0, 100.0);
  }

  // the longest tetbody name: with "_FRAME.vtu" within a file name's 255 bytes
  static constexpr size_t kMaxNameBytes = 200;

  SceneSpec Parse() {
    SceneSpec scene;
    scene.path = path_;
    tinyxml2::XMLDocument document;
    if (!std::filesystem::exists(path_)) ThrowAt(path_, 0, "cannot open: no such file");
    if (std::filesystem::is_directory(path_)) {
      ThrowAt(path_, 0, "is a folder, not a scene file (MJCF with a <deformable> element)");
    }
    if (document.LoadFile(path_.c_str()) != tinyxml2::XML_SUCCESS) {
      ThrowAt(path_, document.ErrorLineNum(),
              "not well-formed XML: " + DescribeXmlError(document) +
                  (document.ErrorLineNum() > 0
                       ? "; mend the file at that line (or the line before)"
                       : "; give an MJCF file (a <mujoco> element holding the scene)"));
    }
    // (names go into summary.json, and JSON is UTF-8)
    std::string text = ReadText();
    if (const std::optional<size_t> bad = FirstNonUtf8Byte(text)) {
      const long line = 1 + std::count(text.begin(), text.begin() + static_cast<long>(*bad), '\n');
      char message[160];
      std::snprintf(message, sizeof(message),
                    "byte 0x%02X (column %zu) is not UTF-8 text; save the scene as UTF-8",
                    static_cast<unsigned char>(text[*bad]), *bad - LineStart(text, line) + 1);
      ThrowAt(path_, line, message);
    }
    XMLElement* root = document.RootElement();
    if (!root || std::string(root->Name()) != "mujoco") {
      ThrowAt(path_, root ? root->GetLineNum() : 0, "the top-level element must be <mujoco>");
    }
    if (const XMLElement* compiler = root->FirstChildElement("compiler")) {
      const char* angle = compiler->Attribute("angle");
      degrees_ = !(angle && std::string(angle) == "radian");
    }
    XMLElement* deformable = root->FirstChildElement("deformable");
    if (deformable && deformable->NextSiblingElement("deformable")) {
      Fail(deformable->NextSiblingElement("deformable"),
           "only one <deformable> element is allowed");
    }
    if (deformable) {
      CheckAttributes(deformable, {});
      std::set<std::string> names;
      // scene-wide settings: one element each (a second silently replaced
      // what the first set)
      std::map<std::string, int> settings_line;
      // a geom's proxy: one (two would count its contacts twice)
      std::map<std::pair<std::string, std::string>, long> proxy_line;
      for (const XMLElement* child = deformable->FirstChildElement(); child;
           child = child->NextSiblingElement()) {
        std::string kind = child->Name();
        if (kind == "contact" || kind == "solver") {
          const auto [at, inserted] = settings_line.insert({kind, child->GetLineNum()});
          if (!inserted) {
            Fail(child, "only one <" + kind +
                            "> is allowed inside <deformable> (the first is on line " +
                            std::to_string(at->second) + "); merge their attributes");
          }
        }
        if (kind == "tetbody") {
          scene.tetbodies.push_back(TetBody(child));
          if (!names.insert(scene.tetbodies.back().name).second) {
            Fail(child, "a tetbody named '" + scene.tetbodies.back().name + "' exists already");
          }
        } else if (kind == "rigidtet") {
          scene.rigidtets.push_back(RigidTet(child));
          const RigidTetSpec& spec = scene.rigidtets.back();
          if (!spec.geom.empty()) {
            const auto [at, inserted] = proxy_line.insert({{spec.body, spec.geom}, spec.line});
            if (!inserted) {
              Fail(child, "geom '" + spec.geom + "' of body '" + spec.body +
                              "' has a <rigidtet> already (line " + std::to_string(at->second) +
                              "); its contacts would count twice: remove one");
            }
          }
        } else if (kind == "attach") {
          scene.attachments.push_back(Attach(child));
        } else if (kind == "contact") {
          CheckAttributes(child, {"method", "stiffness", "damping", "friction", "slip", "stick",
                                  "stickstiffness", "autoproxy", "area"});
          scene.method = Either(child, "method", "consistent", "closest",
                                scene.method == DepthMethod::kConsistent)
                             ? DepthMethod::kConsistent
                             : DepthMethod::kClosest;
          ContactAttributes(child, scene.contact);
          // (0 would divide by zero in the friction damping, mu f_n / v_s, of
          // a sticking contact; 1 um/s is the smallest tried: the slope of
          // tests/scenarios/friction_test.cc holds, gripper.xml solves)
          scene.slip = Number(child, "slip", 1e-6, 1.0);
          scene.stick = Bool(child, "stick", true);
          // (a spring a thousandth as stiff as the normal gives way by a
          // thousand times mu times the depth before it slides; 1000 times
          // stiffer holds within a thousandth of it)
          scene.stick_stiffness = Number(child, "stickstiffness", 1e-3, 1e3);
          scene.auto_proxies = AutoProxiesOf(child);
          scene.contact_area =
              Either(child, "area", "whole", "facing", scene.contact_area == ContactArea::kWhole)
                  ? ContactArea::kWhole
                  : ContactArea::kFacing;
        } else if (kind == "solver") {
          CheckAttributes(child,
                          {"substeps", "linear", "tolerance", "maxiter", "rigid", "constraints"});
          scene.solver.substeps = static_cast<int>(Number(child, "substeps", 1, 1000).value_or(1));
          scene.solver.implicit_rigid =
              Either(child, "rigid", "implicit", "explicit", scene.solver.implicit_rigid);
          scene.solver.linearize_constraints = Either(child, "constraints", "linearized", "lagged",
                                                      scene.solver.linearize_constraints);
          scene.solver.linear_solver =
              Either(child, "linear", "cg", "ldlt",
                     scene.solver.linear_solver == LinearSolver::kConjugateGradient)
                  ? LinearSolver::kConjugateGradient
                  : LinearSolver::kCholesky;
          scene.solver.tolerance = Number(child, "tolerance", 1e-14, 1e-1).value_or(1e-6);
          scene.solver.max_iterations =
              static_cast<int>(Number(child, "maxiter", 1, 1e6).value_or(1000));
        } else {
          Fail(child,
               "unknown element inside <deformable>; use tetbody, rigidtet, attach, contact or "
               "solver");
        }
      }
      for (const AttachSpec& attach : scene.attachments) {
        if (!names.count(attach.tetbody)) {
          const std::vector<std::string_view> known(names.begin(), names.end());
          ThrowAt(path_, attach.line,
                  "<attach>: no tetbody named '" + attach.tetbody + "'; " +
                      (names.empty() ? "the scene has no <tetbody>"
                                     : "the tetbodies: " + QuotedList(known)));
        }
      }
    }
    // the MJCF for MuJoCo: the file's own text with <deformable> blanked out
    // (newlines kept), so that MuJoCo's line numbers are the file's
    if (deformable) {
      size_t begin = LineStart(text, deformable->GetLineNum());
      begin = text.find("<deformable", begin);
      size_t end = text.find("</deformable>", begin);
      size_t self_closing = text.find("/>", begin);
      size_t first_close = text.find('>', begin);
      if (begin == std::string::npos) Fail(deformable, "cannot locate the element in the text");
      if (self_closing != std::string::npos && self_closing + 1 == first_close) {
        end = first_close + 1;
      } else if (end == std::string::npos) {
        Fail(deformable, "</deformable> is missing");
      } else {
        end += std::string("</deformable>").size();
      }
      for (size_t i = begin; i < end; ++i) {
        if (text[i] != '\n') text[i] = ' ';
      }
    }
    scene.mjcf = std::move(text);
    return scene;
  }

  TetBodySpec TetBody(const XMLElement* e) const {
    CheckAttributes(
        e, {"name", "file",  "shape",       "size",      "resolution", "split",         "pos",
            "quat", "euler", "scale",       "density",   "young",      "poisson",       "damping",
            "vel",  "rgba",  "selfcollide", "stiffness", "friction",   "contactdamping"});
    TetBodySpec spec;
    spec.line = e->GetLineNum();
    const char* name = e->Attribute("name");
    if (!name || !*name) Fail(e, "name is required");
    spec.name = name;
    // (--vtk writes NAME_FRAME.vtu, and a file name holds 255 bytes)
    if (spec.name.size() > kMaxNameBytes) {
      Fail(e, "name is " + std::to_string(spec.name.size()) + " bytes long, more than the " +
                  std::to_string(kMaxNameBytes) +
                  " a file name leaves room for (--vtk writes NAME_FRAME.vtu); shorten it");
    }
    for (const char c : spec.name) {
      const auto byte = static_cast<unsigned char>(c);
      if (c != '/' && c != '\\' && byte >= 0x20 && byte != 0x7F) continue;
      char what[64];
      std::snprintf(what, sizeof(what),
                    c == '/' || c == '\\' ? "'%c'" : "a control character (0x%02X)",
                    c == '/' || c == '\\' ? c : byte);
      Fail(e, std::string("name has ") + what +
                  ", which a file name cannot hold (--vtk writes NAME_FRAME.vtu); rename it");
    }
    spec.file = File(e, "file");
    if (const char* shape = e->Attribute("shape")) spec.shape = shape;
    if (spec.file.empty() == spec.shape.empty()) {
      Fail(e, "give either file or shape (box, sphere, cylinder, capsule, torus)");
    }
    for (double s : Numbers(e, "size", 0, 3)) spec.size.push_back(s);
    for (double r : Numbers(e, "resolution", 0, 3)) spec.resolution.push_back(static_cast<int>(r));
    spec.split = static_cast<int>(Number(e, "split", 5, 6).value_or(6));
    if (!spec.shape.empty() && spec.size.empty()) {
      Fail(e, "shape needs size (half-extents or radii, metres)");
    }
    spec.pose = Pose(e);
    spec.scale = Number(e, "scale", 1e-9, 1e9).value_or(1.0);
    spec.material.density = Number(e, "density", 1e-9, 1e9).value_or(1000.0);
    spec.material.young = Number(e, "young", 1e-9, 1e15).value_or(1e5);
    spec.material.poisson = Number(e, "poisson", 0.0, 0.4999).value_or(0.3);
    std::vector<double> damping = Numbers(e, "damping", 0, 2);
    if (!damping.empty()) spec.material.damping_mass = damping[0];
    if (damping.size() > 1) spec.material.damping_stiffness = damping[1];
    std::vector<double> vel = Numbers(e, "vel", 3, 3);
    for (double v : vel) {
      // (at 1e200 m/s the kinetic energy overflowed to inf, and the run
      // reported "ok")
      if (std::abs(v) > kSpeedOfLight) {
        std::ostringstream range;
        range << "vel = " << v << " m/s is faster than light (" << kSpeedOfLight << " m/s)";
        Fail(e, range.str());
      }
    }
    if (!vel.empty()) spec.velocity = Eigen::Vector3d(vel[0], vel[1], vel[2]);
    std::vector<double> rgba = Numbers(e, "rgba", 4, 4);
    if (!rgba.empty()) spec.rgba = Eigen::Vector4d(rgba[0], rgba[1], rgba[2], rgba[3]);
    spec.self_collide = Bool(e, "selfcollide", false);
    spec.contact.stiffness = Number(e, "stiffness", 0.0, 1e15);
    spec.contact.damping = Number(e, "contactdamping", 0.0, 100.0);
    spec.contact.friction = Number(e, "friction", 0.0, 100.0);
    try {
      spec.material.Validate(("tetbody '" + spec.name + "'").c_str());
    } catch (const Error& error) {
      Fail(e, error.what());
    }
    return spec;
  }

  RigidTetSpec RigidTet(const XMLElement* e) const {
    CheckAttributes(e, {"body", "geom", "file", "pos", "quat", "euler", "scale", "resolution"});
    RigidTetSpec spec;
    spec.line = e->GetLineNum();
    const char* body = e->Attribute("body");
    if (!body) Fail(e, "body (a MuJoCo body name) is required");
    spec.body = body;
    if (const char* geom = e->Attribute("geom")) spec.geom = geom;
    spec.file = File(e, "file");
    if (spec.geom.empty() == spec.file.empty()) Fail(e, "give either geom or file");
    spec.pose = Pose(e);
    spec.scale = Number(e, "scale", 1e-9, 1e9).value_or(1.0);
    spec.resolution = static_cast<int>(Number(e, "resolution", 0, 64).value_or(3));
    return spec;
  }

  AttachSpec Attach(const XMLElement* e) const {
    CheckAttributes(e, {"tetbody", "body", "vertices", "box", "sphere"});
    AttachSpec spec;
    spec.line = e->GetLineNum();
    const char* tetbody = e->Attribute("tetbody");
    const char* body = e->Attribute("body");
    if (!tetbody || !body) Fail(e, "tetbody and body are required");
    spec.tetbody = tetbody;
    spec.body = body;
    for (double v : Numbers(e, "vertices", 0, 1000000)) {
      if (v < 0 || v != std::floor(v)) Fail(e, "vertices must be non-negative integers");
      spec.vertices.push_back(static_cast<int>(v));
    }
    std::vector<double> box = Numbers(e, "box", 0, 6);
    if (!box.empty()) {
      if (box.size() != 6) Fail(e, "box takes xmin ymin zmin xmax ymax zmax");
      spec.box = std::make_pair(Eigen::Vector3d(box[0], box[1], box[2]),
                                Eigen::Vector3d(box[3], box[4], box[5]));
    }
    std::vector<double> sphere = Numbers(e, "sphere", 0, 4);
    if (!sphere.empty()) {
      if (sphere.size() != 4) Fail(e, "sphere takes x y z radius");
      spec.sphere = std::make_pair(Eigen::Vector3d(sphere[0], sphere[1], sphere[2]), sphere[3]);
    }
    if (spec.vertices.empty() && !spec.box && !spec.sphere) {
      Fail(e, "choose vertices, box or sphere");
    }
    return spec;
  }

  std::string ReadText() const {
    std::ifstream in(path_, std::ios::binary);
    std::ostringstream content;
    content << in.rdbuf();
    return content.str();
  }

  static size_t LineStart(const std::string& text, long line) {
    size_t position = 0;
    for (long l = 1; l < line && position != std::string::npos; ++l) {
      position = text.find('\n', position);
      if (position != std::string::npos) ++position;
    }
    return position == std::string::npos ? 0 : position;
  }

 private:
  std::string path_;
  bool degrees_ = true;
};

}  // namespace

SceneSpec ParseScene(const std::string& path) {
  return SceneParser(path).Parse();
}

}  // namespace tetcosim
