#include "mesh/generators.h"

#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <iomanip>
#include <map>
#include <numbers>
#include <sstream>
#include <utility>
#include <vector>

#include "mesh/error.h"

namespace tetcosim {
namespace {

// Collects vertices and tetrahedra; every tetrahedron is stored with positive
// volume (two vertices swapped where the map made it negative).
struct MeshBuilder {
  std::vector<Eigen::Vector3d> points;
  std::vector<std::array<int, 4>> tets;

  void AddTet(int a, int b, int c, int d) {
    double volume = SignedTetVolume(points[a], points[b], points[c], points[d]);
    if (volume < 0.0) std::swap(c, d);
    tets.push_back({a, b, c, d});
  }

  RawMesh Finish(std::string source) const {
    RawMesh raw;
    raw.source = std::move(source);
    raw.positions.resize(static_cast<Eigen::Index>(points.size()), 3);
    for (size_t v = 0; v < points.size(); ++v) {
      raw.positions.row(static_cast<Eigen::Index>(v)) = points[v].transpose();
    }
    raw.tets.resize(static_cast<Eigen::Index>(tets.size()), 4);
    for (size_t t = 0; t < tets.size(); ++t) {
      for (int k = 0; k < 4; ++k) raw.tets(static_cast<Eigen::Index>(t), k) = tets[t][k];
    }
    return raw;
  }
};

// Structured grid of cells[0] x cells[1] x cells[2] cells, node (i, j, k)
// placed by map(i, j, k). Each cell is split into 6 tetrahedra along the
// diagonal from the corner nearest the grid centre (a Kuhn split mirrored per
// octant): faces between cells are split the same way from both sides, so
// the mesh is conforming, and no tetrahedron has all four vertices on the
// boundary near a grid edge, so maps that flatten grid edges (cube to ball)
// make no slivers. A periodic axis wraps its last nodes onto the first and
// is not mirrored.
template <typename Map>
void KuhnGrid(const std::array<int, 3>& cells, const std::array<bool, 3>& periodic, Map map,
              MeshBuilder& out) {
  std::array<int, 3> nodes;
  for (int a = 0; a < 3; ++a) nodes[a] = periodic[a] ? cells[a] : cells[a] + 1;
  const int base = static_cast<int>(out.points.size());
  for (int k = 0; k < nodes[2]; ++k) {
    for (int j = 0; j < nodes[1]; ++j) {
      for (int i = 0; i < nodes[0]; ++i) out.points.push_back(map(i, j, k));
    }
  }
  auto node = [&](std::array<int, 3> ijk) {
    for (int a = 0; a < 3; ++a) {
      if (periodic[a]) ijk[a] %= nodes[a];
    }
    return base + ijk[0] + nodes[0] * (ijk[1] + nodes[1] * ijk[2]);
  };
  static constexpr int kPermutations[6][3] = {{0, 1, 2}, {0, 2, 1}, {1, 0, 2},
                                              {1, 2, 0}, {2, 0, 1}, {2, 1, 0}};
  for (int k = 0; k < cells[2]; ++k) {
    for (int j = 0; j < cells[1]; ++j) {
      for (int i = 0; i < cells[0]; ++i) {
        std::array<int, 3> cell = {i, j, k};
        // start corner: the one nearest the centre along mirrored axes
        std::array<int, 3> start;
        for (int a = 0; a < 3; ++a) {
          start[a] = (!periodic[a] && 2 * cell[a] + 1 < cells[a]) ? 1 : 0;
        }
        for (const auto& order : kPermutations) {
          std::array<int, 3> corner = start;
          int v[4];
          v[0] = node({cell[0] + corner[0], cell[1] + corner[1], cell[2] + corner[2]});
          for (int s = 0; s < 3; ++s) {
            corner[order[s]] ^= 1;
            v[s + 1] = node({cell[0] + corner[0], cell[1] + corner[1], cell[2] + corner[2]});
          }
          out.AddTet(v[0], v[1], v[2], v[3]);
        }
      }
    }
  }
}

// square [-1, 1]^2 to the unit disk, smooth and bijective
Eigen::Vector2d SquareToDisk(double x, double y) {
  return {x * std::sqrt(1.0 - y * y / 2.0), y * std::sqrt(1.0 - x * x / 2.0)};
}

// cube [-1, 1]^3 to the unit ball; equals SquareToDisk on z = 0
Eigen::Vector3d CubeToBall(double x, double y, double z) {
  double x2 = x * x;
  double y2 = y * y;
  double z2 = z * z;
  return {x * std::sqrt(1.0 - y2 / 2.0 - z2 / 2.0 + y2 * z2 / 3.0),
          y * std::sqrt(1.0 - z2 / 2.0 - x2 / 2.0 + z2 * x2 / 3.0),
          z * std::sqrt(1.0 - x2 / 2.0 - y2 / 2.0 + x2 * y2 / 3.0)};
}

double GridCoordinate(int i, int n) {
  return -1.0 + 2.0 * i / n;
}

std::string Describe(const char* shape, std::initializer_list<double> size, int resolution) {
  std::ostringstream out;
  out << shape << ":size=";
  bool first = true;
  for (double s : size) {
    out << (first ? "" : ",") << s;
    first = false;
  }
  out << ":res=" << resolution;
  return out.str();
}

// The generators make at most this many tetrahedra (2^24, several
// gigabytes with the mesh's adjacency): a shape beyond it is most likely a
// slip in its sizes (a capsule a million radii long), and would exhaust
// memory or run for hours instead of failing.
constexpr double kMaxGeneratedTets = 1 << 24;

void CheckTetCount(const std::string& description, double tets) {
  if (tets <= kMaxGeneratedTets) return;
  std::ostringstream message;
  message << description << ": would have " << std::setprecision(3) << tets
          << " tetrahedra, more than the " << static_cast<long>(kMaxGeneratedTets)
          << " the generators make; check the sizes, lower the resolution, or mesh the shape "
             "with gmsh";
  throw Error(message.str());
}

// the layers of cells along a length of `length` in cells of `cell`
// (rounded), checked against kMaxGeneratedTets with `tets_per_layer`
int Layers(const std::string& description, double length, double cell, double tets_per_layer) {
  const double layers = std::round(length / cell);
  CheckTetCount(description, layers * tets_per_layer);
  return static_cast<int>(layers);
}

// Starts a mesh of `solid`'s surface (ConeToPoint, ConeToAxis): its
// surface vertices, in order, as out's first points. Returns each of the
// solid's vertices' point in out (-1 for an inner one).
std::vector<int> AddSurfaceVertices(const TetMesh& solid, MeshBuilder& out) {
  std::vector<int> index(solid.num_vertices(), -1);
  for (int v : solid.surface_vertices()) {
    index[v] = static_cast<int>(out.points.size());
    out.points.push_back(solid.positions().row(v).transpose());
  }
  return index;
}

}  // namespace

RawMesh MakeBox(const Eigen::Vector3d& half_size, const Eigen::Vector3i& cells, int tets_per_cell) {
  if (tets_per_cell != 5 && tets_per_cell != 6) {
    throw Error("box: split must be 5 or 6 tetrahedra per cell, not " +
                std::to_string(tets_per_cell));
  }
  MeshBuilder out;
  auto map = [&](int i, int j, int k) {
    return Eigen::Vector3d(half_size.x() * GridCoordinate(i, cells.x()),
                           half_size.y() * GridCoordinate(j, cells.y()),
                           half_size.z() * GridCoordinate(k, cells.z()));
  };
  std::ostringstream source;
  source << "box:size=" << half_size.x() << "," << half_size.y() << "," << half_size.z()
         << ":res=" << cells.x() << "," << cells.y() << "," << cells.z()
         << ":split=" << tets_per_cell;
  CheckTetCount(source.str(),
                static_cast<double>(tets_per_cell) * cells.x() * cells.y() * cells.z());
  if (tets_per_cell == 6) {
    KuhnGrid({cells.x(), cells.y(), cells.z()}, {false, false, false}, map, out);
    return out.Finish(source.str());
  }
  // 5 tetrahedra per cell: the corners of even (i+j+k) parity form a central
  // tetrahedron, each odd corner a tetrahedron with its three neighbours.
  // Parity is global, so neighbouring cells split shared faces alike.
  const int nx = cells.x() + 1;
  const int ny = cells.y() + 1;
  for (int k = 0; k <= cells.z(); ++k) {
    for (int j = 0; j <= cells.y(); ++j) {
      for (int i = 0; i <= cells.x(); ++i) out.points.push_back(map(i, j, k));
    }
  }
  auto node = [&](int i, int j, int k) { return i + nx * (j + ny * k); };
  for (int k = 0; k < cells.z(); ++k) {
    for (int j = 0; j < cells.y(); ++j) {
      for (int i = 0; i < cells.x(); ++i) {
        int central[4];
        int num_central = 0;
        for (int c = 0; c < 8; ++c) {
          int a = c & 1, b = (c >> 1) & 1, d = (c >> 2) & 1;
          if ((i + a + j + b + k + d) % 2 == 0) {
            central[num_central++] = node(i + a, j + b, k + d);
          } else {
            out.AddTet(node(i + a, j + b, k + d), node(i + (1 - a), j + b, k + d),
                       node(i + a, j + (1 - b), k + d), node(i + a, j + b, k + (1 - d)));
          }
        }
        out.AddTet(central[0], central[1], central[2], central[3]);
      }
    }
  }
  return out.Finish(source.str());
}

RawMesh MakeSphere(double radius, int resolution) {
  MeshBuilder out;
  // icosahedron of circumradius 1 around a centre vertex (index 0)
  const double phi = std::numbers::phi;
  out.points.push_back(Eigen::Vector3d::Zero());
  for (double s1 : {-1.0, 1.0}) {
    for (double s2 : {-1.0, 1.0}) {
      out.points.push_back(Eigen::Vector3d(0, s1, s2 * phi).normalized());
      out.points.push_back(Eigen::Vector3d(s1, s2 * phi, 0).normalized());
      out.points.push_back(Eigen::Vector3d(s2 * phi, 0, s1).normalized());
    }
  }
  // faces: the 20 triples of mutually adjacent vertices; the edge of an
  // icosahedron of circumradius 1 is 4 / sqrt(10 + 2 sqrt(5))
  const double edge = 4.0 / std::sqrt(10.0 + 2.0 * std::sqrt(5.0));
  auto adjacent = [&](int a, int b) {
    return std::abs((out.points[a] - out.points[b]).norm() - edge) < 1e-9;
  };
  std::vector<Eigen::Vector3d> face_normals;
  for (int a = 1; a <= 12; ++a) {
    for (int b = a + 1; b <= 12; ++b) {
      for (int c = b + 1; c <= 12 && adjacent(a, b); ++c) {
        if (adjacent(a, c) && adjacent(b, c)) {
          out.AddTet(0, a, b, c);
          face_normals.push_back((out.points[a] + out.points[b] + out.points[c]).normalized());
        }
      }
    }
  }
  const double inradius = face_normals.front().dot(out.points[out.tets.front()[1]]);

  // red refinement: every tetrahedron into 8 (4 corners + an octahedron cut
  // along its shortest diagonal); faces split 1:4 alike from both sides
  for (int level = 0; level < resolution; ++level) {
    std::map<std::pair<int, int>, int> midpoints;
    auto midpoint = [&](int a, int b) {
      auto key = std::minmax(a, b);
      auto [it, inserted] = midpoints.try_emplace({key.first, key.second}, 0);
      if (inserted) {
        it->second = static_cast<int>(out.points.size());
        out.points.push_back(0.5 * (out.points[a] + out.points[b]));
      }
      return it->second;
    };
    std::vector<std::array<int, 4>> coarse;
    coarse.swap(out.tets);
    for (const auto& t : coarse) {
      int m01 = midpoint(t[0], t[1]), m02 = midpoint(t[0], t[2]), m03 = midpoint(t[0], t[3]);
      int m12 = midpoint(t[1], t[2]), m13 = midpoint(t[1], t[3]), m23 = midpoint(t[2], t[3]);
      out.AddTet(t[0], m01, m02, m03);
      out.AddTet(m01, t[1], m12, m13);
      out.AddTet(m02, m12, t[2], m23);
      out.AddTet(m03, m13, m23, t[3]);
      // the octahedron: a diagonal and the four vertices around it, in order
      const std::array<std::array<int, 6>, 3> choices = {{{m01, m23, m02, m12, m13, m03},
                                                          {m02, m13, m01, m12, m23, m03},
                                                          {m03, m12, m01, m02, m23, m13}}};
      const std::array<int, 6>* best = &choices[0];
      for (const auto& c : choices) {
        if ((out.points[c[0]] - out.points[c[1]]).squaredNorm() <
            (out.points[(*best)[0]] - out.points[(*best)[1]]).squaredNorm() - 1e-12) {
          best = &c;
        }
      }
      const auto& o = *best;
      for (int r = 0; r < 4; ++r) out.AddTet(o[0], o[1], o[2 + r], o[2 + (r + 1) % 4]);
    }
  }
  // map the refined icosahedron onto the ball: a point at fraction s of the
  // way from the centre to the icosahedron's surface goes to fraction s of
  // the radius, in the same direction
  for (Eigen::Vector3d& p : out.points) {
    double length = p.norm();
    if (length == 0.0) continue;
    double best = 0.0;
    for (const Eigen::Vector3d& n : face_normals) best = std::max(best, n.dot(p) / length);
    p *= radius * best / inradius;
  }
  // positive volumes may have changed under the map only for degenerate
  // input; re-check them
  for (auto& t : out.tets) {
    if (SignedTetVolume(out.points[t[0]], out.points[t[1]], out.points[t[2]], out.points[t[3]]) <
        0) {
      std::swap(t[2], t[3]);
    }
  }
  return out.Finish(Describe("sphere", {radius}, resolution));
}

RawMesh MakeCylinder(double radius, double half_height, int resolution) {
  MeshBuilder out;
  const int n = resolution;
  const int nz = std::max(1, Layers(Describe("cylinder", {radius, half_height}, resolution),
                                    half_height * n, radius, 6.0 * n * n));
  KuhnGrid(
      {n, n, nz}, {false, false, false},
      [&](int i, int j, int k) {
        Eigen::Vector2d xy = radius * SquareToDisk(GridCoordinate(i, n), GridCoordinate(j, n));
        return Eigen::Vector3d(xy.x(), xy.y(), half_height * GridCoordinate(k, nz));
      },
      out);
  return out.Finish(Describe("cylinder", {radius, half_height}, resolution));
}

RawMesh MakeCapsule(double radius, double half_length, int resolution) {
  MeshBuilder out;
  const int n = resolution;
  const int cap = std::max(1, (n + 1) / 2);
  const int middle = Layers(Describe("capsule", {radius, half_length}, resolution), half_length * n,
                            radius, 6.0 * n * n);
  const int nz = 2 * cap + middle;
  KuhnGrid(
      {n, n, nz}, {false, false, false},
      [&](int i, int j, int k) {
        double x = GridCoordinate(i, n);
        double y = GridCoordinate(j, n);
        if (k < cap || k > cap + middle) {
          // a cap: half of the cube-to-ball map, moved to the cylinder's end
          double w = k < cap ? -static_cast<double>(cap - k) / cap
                             : static_cast<double>(k - cap - middle) / cap;
          Eigen::Vector3d p = radius * CubeToBall(x, y, w);
          p.z() += k < cap ? -half_length : half_length;
          return p;
        }
        Eigen::Vector2d xy = radius * SquareToDisk(x, y);
        double z = middle == 0 ? 0.0 : half_length * (-1.0 + 2.0 * (k - cap) / middle);
        return Eigen::Vector3d(xy.x(), xy.y(), z);
      },
      out);
  return out.Finish(Describe("capsule", {radius, half_length}, resolution));
}

RawMesh ConeToPoint(const TetMesh& solid, const Eigen::Vector3d& apex) {
  const Triangles& surface = solid.surface();
  MeshBuilder out;
  const std::vector<int> index = AddSurfaceVertices(solid, out);
  const int centre = static_cast<int>(out.points.size());
  out.points.push_back(apex);
  out.tets.reserve(surface.rows());
  for (Eigen::Index f = 0; f < surface.rows(); ++f) {
    // (counter-clockwise seen from outside: (a, c, b, apex) is positive
    // just when the triangle faces away from the apex)
    const int a = index[surface(f, 0)], b = index[surface(f, 1)], c = index[surface(f, 2)];
    if (!(SignedTetVolume(out.points[a], out.points[c], out.points[b], apex) > 0.0)) {
      throw Error(solid.source() + ": surface triangle " + std::to_string(f) +
                  " does not face away from the point the mesh is coned to; the surface "
                  "must be seen whole from it");
    }
    out.tets.push_back({a, c, b, centre});
  }
  return out.Finish("the surface of " + solid.source() + " coned to a point");
}

RawMesh ConeToAxis(const TetMesh& solid, double half_length) {
  const Positions& x = solid.positions();
  const Triangles& surface = solid.surface();
  const double side_limit = half_length * (1.0 + 1e-12);
  // the rings' heights, ascending, and whether there are caps beyond them
  std::vector<double> levels;
  double bottom = 0.0, top = 0.0;
  for (int v : solid.surface_vertices()) {
    const double z = x(v, 2);
    bottom = std::min(bottom, z);
    top = std::max(top, z);
    if (std::abs(z) <= side_limit) levels.push_back(z);
  }
  std::sort(levels.begin(), levels.end());
  levels.erase(std::unique(levels.begin(), levels.end()), levels.end());
  const int num_levels = static_cast<int>(levels.size());
  const bool caps = num_levels > 0 && bottom < levels.front() && top > levels.back();
  if (num_levels < (caps ? 1 : 2)) {
    throw Error(solid.source() + ": no rings along the axis within the half-length " +
                std::to_string(half_length) + " m to cone the surface to; the mesh must be a " +
                "cylinder's or a capsule's along z");
  }
  // slabs: 0 .. num_levels - 2 between the levels, and with caps the bottom
  // cap (num_levels - 1) and the top one (num_levels)
  const int num_between = num_levels - 1;
  const int bottom_cap = num_between, top_cap = num_between + 1;
  auto slab_of = [&](double z) {
    if (caps && z < levels.front()) return bottom_cap;
    if (caps && z > levels.back()) return top_cap;
    const auto above = std::upper_bound(levels.begin(), levels.end(), z);
    return std::clamp(static_cast<int>(above - levels.begin()) - 1, 0, num_between - 1);
  };
  MeshBuilder out;
  const std::vector<int> index = AddSurfaceVertices(solid, out);
  std::vector<int> apex(num_between + (caps ? 2 : 0));
  for (int s = 0; s < num_between; ++s) {
    apex[s] = static_cast<int>(out.points.size());
    out.points.emplace_back(0.0, 0.0, 0.5 * (levels[s] + levels[s + 1]));
  }
  if (caps) {
    apex[bottom_cap] = static_cast<int>(out.points.size());
    out.points.emplace_back(0.0, 0.0, 0.5 * (bottom + levels.front()));
    apex[top_cap] = static_cast<int>(out.points.size());
    out.points.emplace_back(0.0, 0.0, 0.5 * (top + levels.back()));
  }
  auto add = [&](int a, int b, int c, int d, const char* what, Eigen::Index which) {
    if (!(SignedTetVolume(out.points[a], out.points[b], out.points[c], out.points[d]) > 0.0)) {
      throw Error(solid.source() + ": " + what + " " + std::to_string(which) +
                  " does not face away from the point it is coned to; the mesh must be a "
                  "cylinder's or a capsule's along z");
    }
    out.tets.push_back({a, b, c, d});
  };
  // each surface triangle to its slab's point, and each edge of a ring
  // between two slabs (both ends at its height: the rings' edges, on the
  // side; a cylinder's end discs are not between slabs), once
  std::vector<std::array<int, 3>> ring_edges;  // (level, a, b), a < b
  for (Eigen::Index f = 0; f < surface.rows(); ++f) {
    const int a = surface(f, 0), b = surface(f, 1), c = surface(f, 2);
    const double centre_z = (x(a, 2) + x(b, 2) + x(c, 2)) / 3.0;
    add(index[a], index[c], index[b], apex[slab_of(centre_z)], "surface triangle", f);
    for (const auto& [p, q] : {std::pair{a, b}, std::pair{b, c}, std::pair{c, a}}) {
      if (x(p, 2) != x(q, 2) || std::abs(x(p, 2)) > side_limit) continue;
      const int level = static_cast<int>(std::lower_bound(levels.begin(), levels.end(), x(p, 2)) -
                                         levels.begin());
      if (!caps && (level == 0 || level == num_levels - 1)) continue;
      ring_edges.push_back({level, std::min(p, q), std::max(p, q)});
    }
  }
  std::sort(ring_edges.begin(), ring_edges.end());
  ring_edges.erase(std::unique(ring_edges.begin(), ring_edges.end()), ring_edges.end());
  std::vector<int> axis(num_levels, -1);  // the axis's point at each fanned level
  for (const auto& [level, a, b] : ring_edges) {
    if (axis[level] < 0) {
      axis[level] = static_cast<int>(out.points.size());
      out.points.emplace_back(0.0, 0.0, levels[level]);
    }
    const int below = level > 0 ? apex[level - 1] : apex[bottom_cap];
    const int above = level < num_between ? apex[level] : apex[top_cap];
    // (the fan's triangle (axis, a, b) faces one way to one slab's point,
    // the other way to the other's)
    const bool up = SignedTetVolume(out.points[axis[level]], out.points[index[a]],
                                    out.points[index[b]], out.points[above]) > 0.0;
    const int first = up ? index[a] : index[b], second = up ? index[b] : index[a];
    add(axis[level], first, second, above, "ring edge at level", level);
    add(axis[level], second, first, below, "ring edge at level", level);
  }
  // (a mesh whose rings are not where a cylinder's or a capsule's are
  // could leave gaps between its slabs)
  double volume = 0.0;
  for (const auto& [a, b, c, d] : out.tets) {
    volume += SignedTetVolume(out.points[a], out.points[b], out.points[c], out.points[d]);
  }
  if (!(std::abs(volume - solid.total_volume()) <= 1e-9 * solid.total_volume())) {
    throw Error(solid.source() + ": coned to its axis, it holds " + std::to_string(volume) +
                " m^3, not its " + std::to_string(solid.total_volume()) +
                "; the mesh must be a cylinder's or a capsule's along z");
  }
  return out.Finish("the surface of " + solid.source() + " coned to its axis");
}

RawMesh MakeTorus(double major_radius, double minor_radius, int resolution) {
  MeshBuilder out;
  const int n = resolution;
  const double cell = 2.0 * minor_radius / n;
  const int segments =
      std::max(8, Layers(Describe("torus", {major_radius, minor_radius}, resolution),
                         2.0 * std::numbers::pi * major_radius, cell, 6.0 * n * n));
  KuhnGrid(
      {n, n, segments}, {false, false, true},
      [&](int i, int j, int k) {
        Eigen::Vector2d uv =
            minor_radius * SquareToDisk(GridCoordinate(i, n), GridCoordinate(j, n));
        double angle = 2.0 * std::numbers::pi * k / segments;
        double ring = major_radius + uv.x();
        return Eigen::Vector3d(ring * std::cos(angle), ring * std::sin(angle), uv.y());
      },
      out);
  return out.Finish(Describe("torus", {major_radius, minor_radius}, resolution));
}

namespace {

constexpr const char* kShapes[] = {"box", "sphere", "cylinder", "capsule", "torus"};

template <typename T>
std::vector<T> ParseList(const std::string& text, const std::string& what,
                         const std::string& where) {
  std::vector<T> values;
  size_t start = 0;
  while (start <= text.size()) {
    size_t end = text.find(',', start);
    if (end == std::string::npos) end = text.size();
    std::string item = text.substr(start, end - start);
    T value{};
    auto [ptr, ec] = std::from_chars(item.data(), item.data() + item.size(), value);
    if (item.empty() || ec != std::errc() || ptr != item.data() + item.size()) {
      // NOLINTNEXTLINE(performance-inefficient-string-concatenation): once, on failure
      throw Error(where + ": " + what + " '" + text + "' is not a list of numbers");
    }
    values.push_back(value);
    start = end + 1;
  }
  return values;
}

}  // namespace

bool IsShapeSpec(const std::string& text) {
  std::string shape = text.substr(0, text.find(':'));
  for (const char* s : kShapes) {
    if (shape == s && (text.size() == shape.size() || text[shape.size()] == ':')) return true;
  }
  return false;
}

RawMesh MakeShape(const std::string& shape, const std::vector<double>& size,
                  const std::vector<int>& resolution, int split, const std::string& where) {
  auto fail = [&](const std::string& message) -> void { throw Error(where + ": " + message); };
  // (outside this range the volumes of the elements overflow or underflow:
  // a 1e300 m box was refused as degenerate, its volume NaN)
  constexpr double kMinSize = 1e-9, kMaxSize = 1e9;
  for (double s : size) {
    if (!(s >= kMinSize && s <= kMaxSize)) {
      char message[128];
      std::snprintf(message, sizeof(message),
                    "size %g is not a length from 1e-9 to 1e9 metres; give one in that range", s);
      fail(message);
    }
  }
  for (int r : resolution) {
    if (r < 0 || r > 256) fail("resolution " + std::to_string(r) + " is outside 0..256");
  }
  auto expect_sizes = [&](size_t count, const char* meaning) {
    if (size.size() != count) {
      fail(shape + " takes " + std::to_string(count) + " size value(s): " + meaning + "; got " +
           std::to_string(size.size()));
    }
  };
  auto one_resolution = [&](int fallback, int minimum) {
    if (resolution.size() > 1) fail(shape + " takes one resolution value");
    int r = resolution.empty() ? fallback : resolution[0];
    if (r < minimum) fail(shape + " needs resolution >= " + std::to_string(minimum));
    return r;
  };
  if (shape == "box") {
    if (size.size() != 1 && size.size() != 3) fail("box takes size hx,hy,hz (half-extents) or h");
    Eigen::Vector3d half = size.size() == 1 ? Eigen::Vector3d::Constant(size[0])
                                            : Eigen::Vector3d(size[0], size[1], size[2]);
    Eigen::Vector3i cells = Eigen::Vector3i::Constant(4);
    if (resolution.size() == 1) cells.setConstant(resolution[0]);
    if (resolution.size() == 3) {
      cells = Eigen::Vector3i(resolution[0], resolution[1], resolution[2]);
    }
    if (resolution.size() == 2 || resolution.size() > 3) fail("box takes 1 or 3 resolution values");
    if (cells.minCoeff() < 1) fail("box needs at least 1 cell per axis");
    if (split != 5 && split != 6) fail("split must be 5 or 6");
    return MakeBox(half, cells, split);
  }
  if (shape == "sphere") {
    expect_sizes(1, "the radius");
    int r = one_resolution(1, 0);
    if (r > 5) fail("sphere resolution above 5 (over 650,000 tetrahedra) is not supported");
    return MakeSphere(size[0], r);
  }
  if (shape == "cylinder") {
    expect_sizes(2, "radius and half-height");
    return MakeCylinder(size[0], size[1], one_resolution(4, 1));
  }
  if (shape == "capsule") {
    expect_sizes(2, "radius and half-length of the cylinder part");
    return MakeCapsule(size[0], size[1], one_resolution(4, 1));
  }
  if (shape == "torus") {
    expect_sizes(2, "major radius and minor (tube) radius");
    if (size[1] >= size[0]) fail("the torus tube radius must be smaller than its major radius");
    return MakeTorus(size[0], size[1], one_resolution(4, 1));
  }
  fail("unknown shape '" + shape + "'; use box, sphere, cylinder, capsule or torus");
  return {};
}

RawMesh MakeShape(const std::string& spec) {
  std::vector<std::string> parts;
  size_t start = 0;
  while (true) {
    size_t end = spec.find(':', start);
    parts.push_back(spec.substr(start, end == std::string::npos ? std::string::npos : end - start));
    if (end == std::string::npos) break;
    start = end + 1;
  }
  const std::string where = "shape '" + spec + "'";
  std::vector<double> size;
  std::vector<int> resolution;
  int split = 6;
  for (size_t i = 1; i < parts.size(); ++i) {
    size_t eq = parts[i].find('=');
    std::string key = parts[i].substr(0, eq);
    std::string value = eq == std::string::npos ? "" : parts[i].substr(eq + 1);
    if (key == "size") {
      size = ParseList<double>(value, "size", where);
    } else if (key == "res") {
      resolution = ParseList<int>(value, "res", where);
    } else if (key == "split") {
      std::vector<int> s = ParseList<int>(value, "split", where);
      if (s.size() != 1) throw Error(where + ": split takes one value, 5 or 6");
      split = s[0];
    } else {
      // NOLINTNEXTLINE(performance-inefficient-string-concatenation): once, on failure
      throw Error(where + ": unknown key '" + key + "'; use size=, res= and (box) split=");
    }
  }
  if (size.empty()) throw Error(where + ": size= is missing (half-extents or radii, in metres)");
  RawMesh raw = MakeShape(parts[0], size, resolution, split, where);
  raw.source = spec;
  return raw;
}

}  // namespace tetcosim
