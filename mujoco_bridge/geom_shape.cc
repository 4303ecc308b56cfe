#include "mujoco_bridge/geom_shape.h"

#include <mujoco/mujoco.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <map>
#include <utility>

#include "mesh/error.h"
#include "mesh/generators.h"

namespace tetcosim {
namespace {

// Faces of a convex hull closer than this (unit normals, and offsets over
// the hull's size) are one plane.
constexpr double kSamePlane = 1e-12;

// ConvexHullTetMesh stops splitting faces once there are this many.
constexpr size_t kMaxHullTriangles = 20000;

// vertex i of mesh `mesh` (geom frame; MuJoCo keeps them in single precision)
Eigen::Vector3d MeshVertex(const mjModel* m, int mesh, int i) {
  const float* x = m->mesh_vert + 3 * (m->mesh_vertadr[mesh] + i);
  return Eigen::Vector3d(x[0], x[1], x[2]);
}

// Mesh `mesh`'s convex hull as MuJoCo's graph of it gives it (mesh_graph:
// numvert, numface, vert_edgeadr (numvert), vert_globalid (numvert),
// edge_localid (numvert + 3 numface), face_globalid (3 numface), the last
// two indices into the mesh's vertices).
struct HullGraph {
  int num_vertices;
  int num_faces;
  const int* vertex_id;  // (num_vertices)
  const int* face;       // (3 num_faces): the corners of each face
};

HullGraph ReadHullGraph(const mjModel* m, int mesh) {
  const int* graph = m->mesh_graph + m->mesh_graphadr[mesh];
  return {graph[0], graph[1], graph + 2 + graph[0], graph + 2 + 3 * graph[0] + 3 * graph[1]};
}

// The mesh of mesh geom `geom`, after checking that MuJoCo made its convex
// hull (a mesh compiled with convexhull="false" has none): throws Error,
// naming `where`, if not.
int HulledMesh(const mjModel* m, int geom, const std::string& where) {
  const int mesh = m->geom_dataid[geom];
  if (mesh < 0 || m->mesh_graphadr[mesh] < 0) {
    throw Error(where +
                ": its mesh has no convex hull, which deformables collide with "
                "as MuJoCo does; remove convexhull=\"false\" from <compiler>, or "
                "give the geom a <rigidtet>, or keep it off deformables "
                "(contype and conaffinity both even)");
  }
  return mesh;
}

// The planes of the faces of mesh `mesh`'s convex hull.
void HullPlanes(const mjModel* m, int mesh, GeomShape& shape) {
  const auto [num_vertices, num_faces, vertex_id, face] = ReadHullGraph(m, mesh);
  auto vertex = [&](int i) { return MeshVertex(m, mesh, i); };
  // a point inside: the mean of the hull's vertices
  Eigen::Vector3d inside = Eigen::Vector3d::Zero();
  double radius = 0.0;
  for (int k = 0; k < num_vertices; ++k) inside += vertex(vertex_id[k]);
  inside /= std::max(1, num_vertices);
  for (int k = 0; k < num_vertices; ++k) {
    radius = std::max(radius, (vertex(vertex_id[k]) - inside).norm());
  }
  for (int f = 0; f < num_faces; ++f) {
    const Eigen::Vector3d a = vertex(face[3 * f]);
    Eigen::Vector3d n = (vertex(face[3 * f + 1]) - a).cross(vertex(face[3 * f + 2]) - a);
    if (!(n.norm() > 0.0)) continue;  // (a degenerate face: its neighbours bound the hull)
    // (the cone from the inside point: |n . (a - inside)| / 6)
    shape.hull_volume += std::abs(n.dot(a - inside)) / 6.0;
    n.normalize();
    if (n.dot(inside - a) > 0.0) n = -n;  // (outward, whatever the winding)
    const double offset = n.dot(a);
    bool known = false;
    for (size_t i = 0; i < shape.plane_normal.size() && !known; ++i) {
      known = (shape.plane_normal[i] - n).norm() < kSamePlane &&
              std::abs(shape.plane_offset[i] - offset) < kSamePlane * radius;
    }
    if (known) continue;
    shape.plane_normal.push_back(n);
    shape.plane_offset.push_back(offset);
  }
}

bool MeshPenetration(const GeomShape& shape, const Eigen::Vector3d& p, double& depth,
                     Eigen::Vector3d& direction) {
  // inside a convex polyhedron, the nearest surface point lies on the
  // nearest face plane: depth = -max_f (n_f . p - offset_f)
  double highest = -std::numeric_limits<double>::infinity();
  int nearest = -1;
  for (size_t f = 0; f < shape.plane_normal.size(); ++f) {
    const double height = shape.plane_normal[f].dot(p) - shape.plane_offset[f];
    if (height >= 0.0) return false;
    if (height > highest) {
      highest = height;
      nearest = static_cast<int>(f);
    }
  }
  if (nearest < 0) return false;
  depth = -highest;
  direction = shape.plane_normal[nearest];
  return true;
}

bool HeightFieldPenetration(const GeomShape& shape, const Eigen::Vector3d& p, double& depth,
                            Eigen::Vector3d& direction) {
  const double* size = shape.size;
  if (!(std::abs(p.x()) <= size[0] && std::abs(p.y()) <= size[1] && p.z() >= -size[3])) {
    return false;
  }
  // the cell over p and p's place in it, u along x (columns), v along y
  // (rows), both 0 to 1
  const double cell_x = 2.0 * size[0] / (shape.cols - 1);
  const double cell_y = 2.0 * size[1] / (shape.rows - 1);
  double u = (p.x() + size[0]) / cell_x;
  double v = (p.y() + size[1]) / cell_y;
  const int c = std::clamp(static_cast<int>(std::floor(u)), 0, shape.cols - 2);
  const int r = std::clamp(static_cast<int>(std::floor(v)), 0, shape.rows - 2);
  u -= c;
  v -= r;
  auto height = [&](int row, int col) { return size[2] * shape.elevation[row * shape.cols + col]; };
  const double h00 = height(r, c), h01 = height(r, c + 1);
  const double h10 = height(r + 1, c), h11 = height(r + 1, c + 1);
  // MuJoCo splits a cell along its diagonal from (r, c) to (r + 1, c + 1):
  // h = h00 + dh_du u + dh_dv v on the triangle p is over
  double dh_du, dh_dv;
  if (v >= u) {  // (r, c), (r + 1, c), (r + 1, c + 1)
    dh_du = h11 - h10;
    dh_dv = h10 - h00;
  } else {  // (r, c), (r, c + 1), (r + 1, c + 1)
    dh_du = h01 - h00;
    dh_dv = h11 - h01;
  }
  const double h = h00 + dh_du * u + dh_dv * v;
  if (!(p.z() < h)) return false;
  // the distance to the triangle's plane, along its upward normal
  direction = Eigen::Vector3d(-dh_du / cell_x, -dh_dv / cell_y, 1.0).normalized();
  depth = (h - p.z()) * direction.z();
  return true;
}

// The part [t_in, t_out] of the line o + t d inside a solid, and which of
// the solid's surfaces the line enters through (`face`: a shape's own
// numbering). Empty where t_in > t_out.
struct Interval {
  double t_in = -std::numeric_limits<double>::infinity();
  double t_out = std::numeric_limits<double>::infinity();
  int face = -1;
};

// the line inside both a and b (a convex solid's constraints together)
Interval Intersect(const Interval& a, const Interval& b) {
  Interval both = b.t_in > a.t_in ? b : a;
  both.t_out = std::min(a.t_out, b.t_out);
  return both;
}

// where a t^2 + b t + c <= 0, a > 0 (empty if never)
Interval QuadraticInterval(double a, double b, double c, int face) {
  Interval inside;
  inside.face = face;
  const double discriminant = b * b - 4.0 * a * c;
  if (!(a > 0.0) || !(discriminant >= 0.0)) {
    inside.t_in = std::numeric_limits<double>::infinity();
    inside.t_out = -std::numeric_limits<double>::infinity();
    return inside;
  }
  // (the root of the larger magnitude first, without cancellation)
  const double q = -0.5 * (b + std::copysign(std::sqrt(discriminant), b));
  double t0 = q / a;
  double t1 = q != 0.0 ? c / q : t0;
  inside.t_in = std::min(t0, t1);
  inside.t_out = std::max(t0, t1);
  return inside;
}

// the line inside the ball |x - centre| <= r
Interval BallInterval(const Eigen::Vector3d& o, const Eigen::Vector3d& d,
                      const Eigen::Vector3d& centre, double r, int face) {
  const Eigen::Vector3d c = o - centre;
  return QuadraticInterval(d.squaredNorm(), 2.0 * c.dot(d), c.squaredNorm() - r * r, face);
}

// the line inside the infinite cylinder x^2 + y^2 <= r^2 (the z axis)
Interval RoundInterval(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double r, int face) {
  const double a = d.x() * d.x() + d.y() * d.y();
  const double c = o.x() * o.x() + o.y() * o.y() - r * r;
  if (a == 0.0) {  // (along the axis: inside throughout, or never)
    Interval inside;
    inside.face = face;
    if (c > 0.0) std::swap(inside.t_in, inside.t_out);
    return inside;
  }
  return QuadraticInterval(a, 2.0 * (o.x() * d.x() + o.y() * d.y()), c, face);
}

// the line inside the half-space n . x <= offset
Interval HalfSpaceInterval(const Eigen::Vector3d& o, const Eigen::Vector3d& d,
                           const Eigen::Vector3d& n, double offset, int face) {
  Interval inside;
  inside.face = face;
  const double height = n.dot(o) - offset;
  const double rate = n.dot(d);
  if (rate < 0.0) {
    inside.t_in = -height / rate;
  } else if (rate > 0.0) {
    inside.t_out = -height / rate;
  } else if (height > 0.0) {
    std::swap(inside.t_in, inside.t_out);
  }
  return inside;
}

// the line inside the slab |x_axis| <= half (faces 2 axis and 2 axis + 1:
// the slab's low and high sides)
Interval SlabInterval(const Eigen::Vector3d& o, const Eigen::Vector3d& d, int axis, double half) {
  const Eigen::Vector3d e = Eigen::Vector3d::Unit(axis);
  return Intersect(HalfSpaceInterval(o, d, -e, half, 2 * axis),
                   HalfSpaceInterval(o, d, e, half, 2 * axis + 1));
}

// the outward normal of a slab's face (SlabInterval's numbering)
Eigen::Vector3d SlabNormal(int face) {
  return Eigen::Vector3d::Unit(face / 2) * (face % 2 == 0 ? -1.0 : 1.0);
}

}  // namespace

Eigen::Vector3d MeshExtent(const mjModel* m, int geom) {
  const int mesh = m->geom_dataid[geom];
  if (mesh < 0 || m->mesh_vertnum[mesh] == 0) return Eigen::Vector3d::Zero();
  Eigen::Vector3d lo = MeshVertex(m, mesh, 0), hi = lo;
  for (int i = 1; i < m->mesh_vertnum[mesh]; ++i) {
    lo = lo.cwiseMin(MeshVertex(m, mesh, i));
    hi = hi.cwiseMax(MeshVertex(m, mesh, i));
  }
  return hi - lo;
}

double GeomPassageWidth(const mjModel* m, int geom) {
  const double* size = m->geom_size + 3 * geom;
  std::array<double, 3> extent{};
  switch (m->geom_type[geom]) {
    case mjGEOM_SPHERE:
    case mjGEOM_CAPSULE:
    case mjGEOM_CYLINDER:  // (a disc edge-on: 2 h by 2 r, as wide as it is long)
      return 2.0 * size[0];
    case mjGEOM_BOX:
    case mjGEOM_ELLIPSOID:
      extent = {2.0 * size[0], 2.0 * size[1], 2.0 * size[2]};
      break;
    case mjGEOM_MESH: {
      const Eigen::Vector3d e = MeshExtent(m, geom);
      extent = {e.x(), e.y(), e.z()};
      break;
    }
    default:  // plane, height field: unbounded
      return std::numeric_limits<double>::infinity();
  }
  std::sort(extent.begin(), extent.end());
  return extent[1];
}

RawMesh ConvexHullTetMesh(const mjModel* m, int geom, double max_edge, const std::string& where) {
  const int mesh = HulledMesh(m, geom, where);
  const auto [num_hull, num_faces, hull_vertex, face] = ReadHullGraph(m, mesh);
  // the hull's vertices, numbered 0 .. num_hull - 1, and their mean
  std::vector<Eigen::Vector3d> points;
  std::vector<int> local(static_cast<size_t>(m->mesh_vertnum[mesh]), -1);
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  for (int k = 0; k < num_hull; ++k) {
    local[static_cast<size_t>(hull_vertex[k])] = k;
    points.push_back(MeshVertex(m, mesh, hull_vertex[k]));
    centre += points.back();
  }
  centre /= std::max(1, num_hull);
  std::vector<std::array<int, 3>> triangles;
  triangles.reserve(static_cast<size_t>(num_faces));
  for (int f = 0; f < num_faces; ++f) {
    triangles.push_back({local[static_cast<size_t>(face[3 * f])],
                         local[static_cast<size_t>(face[3 * f + 1])],
                         local[static_cast<size_t>(face[3 * f + 2])]});
  }
  // a triangle's longest edge: its corners k and k + 1
  auto longest_edge = [&](const std::array<int, 3>& t) {
    int best = 0;
    for (int k = 1; k < 3; ++k) {
      if ((points[t[(k + 1) % 3]] - points[t[k]]).squaredNorm() >
          (points[t[(best + 1) % 3]] - points[t[best]]).squaredNorm()) {
        best = k;
      }
    }
    return best;
  };
  // every face outward, as seen from the centre
  for (std::array<int, 3>& t : triangles) {
    const Eigen::Vector3d normal = (points[t[1]] - points[t[0]]).cross(points[t[2]] - points[t[0]]);
    if (normal.dot(points[t[0]] - centre) < 0.0) std::swap(t[1], t[2]);
  }
  // Longest-edge bisection (after Rivara): each pass halves the longest
  // edge of every face whose longest edge is longer than max_edge, and each
  // face takes the midpoints of its edges that were halved (one: two faces;
  // two: three; three: four), so that faces meet edge to edge. Midpoints
  // lie on the hull (on a face, or on the hull's edge). Only long edges are
  // split, but thin faces stay thin (a 1 x 20 cm rod's hull at 6 mm:
  // 11,440 faces where about 800 would do).
  while (triangles.size() < kMaxHullTriangles) {
    std::map<std::pair<int, int>, int> midpoints;
    for (const std::array<int, 3>& t : triangles) {
      const int k = longest_edge(t);
      const int a = t[k], b = t[(k + 1) % 3];
      if ((points[b] - points[a]).norm() > max_edge) midpoints.try_emplace(std::minmax(a, b), -1);
    }
    if (midpoints.empty()) break;
    for (auto& [edge, point] : midpoints) {
      point = static_cast<int>(points.size());
      points.push_back(0.5 * (points[edge.first] + points[edge.second]));
    }
    auto midpoint = [&](int a, int b) {
      const auto it = midpoints.find(std::minmax(a, b));
      return it == midpoints.end() ? -1 : it->second;
    };
    std::vector<std::array<int, 3>> coarse;
    coarse.swap(triangles);
    for (const std::array<int, 3>& t : coarse) {
      const std::array<int, 3> mid = {midpoint(t[0], t[1]), midpoint(t[1], t[2]),
                                      midpoint(t[2], t[0])};  // (mid[k]: edge k, k + 1)
      const int split = (mid[0] >= 0) + (mid[1] >= 0) + (mid[2] >= 0);
      if (split == 0) {
        triangles.push_back(t);
      } else if (split == 3) {
        triangles.push_back({t[0], mid[0], mid[2]});
        triangles.push_back({mid[0], t[1], mid[1]});
        triangles.push_back({mid[2], mid[1], t[2]});
        triangles.push_back({mid[0], mid[1], mid[2]});
      } else {
        // turned so that edge 0 (corners a, b) is split, and edge 2 (c, a)
        // is not: with one split, a m b, c; with two, edge 1 (b, c) too
        int k = 0;
        while (!(mid[k] >= 0 && mid[(k + 2) % 3] < 0)) ++k;
        const int a = t[k], b = t[(k + 1) % 3], c = t[(k + 2) % 3];
        const int ab = mid[k], bc = mid[(k + 1) % 3];
        if (split == 1) {
          triangles.push_back({a, ab, c});
          triangles.push_back({ab, b, c});
        } else {
          triangles.push_back({ab, b, bc});
          triangles.push_back({a, ab, bc});
          triangles.push_back({a, bc, c});
        }
      }
    }
  }
  // a tetrahedron from each face to the centre (positive: the face is
  // outward, so that its corners turn clockwise seen from the centre, and
  // the hull is convex around the centre)
  RawMesh raw;
  raw.positions.resize(static_cast<Eigen::Index>(points.size()) + 1, 3);
  for (size_t v = 0; v < points.size(); ++v) {
    raw.positions.row(static_cast<Eigen::Index>(v)) = points[v].transpose();
  }
  const int apex = static_cast<int>(points.size());
  raw.positions.row(apex) = centre.transpose();
  raw.tets.resize(static_cast<Eigen::Index>(triangles.size()), 4);
  for (size_t f = 0; f < triangles.size(); ++f) {
    raw.tets.row(static_cast<Eigen::Index>(f)) << triangles[f][0], triangles[f][2], triangles[f][1],
        apex;
  }
  raw.source = where + ": its convex hull";
  return raw;
}

GeomShape MakeGeomShape(const mjModel* m, int geom, const std::string& where) {
  GeomShape shape;
  shape.type = m->geom_type[geom];
  shape.size = m->geom_size + 3 * geom;
  if (shape.type == mjGEOM_MESH) {
    const int mesh = HulledMesh(m, geom, where);
    HullPlanes(m, mesh, shape);
    // the mesh's own volume, sum of a . (b x c) / 6 over its faces (either
    // winding, if the same throughout)
    const int* faces = m->mesh_face + 3 * m->mesh_faceadr[mesh];
    auto vertex = [&](int i) { return MeshVertex(m, mesh, i); };
    double volume = 0.0;
    for (int f = 0; f < m->mesh_facenum[mesh]; ++f) {
      volume += vertex(faces[3 * f]).dot(vertex(faces[3 * f + 1]).cross(vertex(faces[3 * f + 2])));
    }
    shape.mesh_volume = std::min(std::abs(volume) / 6.0, shape.hull_volume);
  } else if (shape.type == mjGEOM_HFIELD) {
    const int field = m->geom_dataid[geom];
    shape.size = m->hfield_size + 4 * field;
    shape.rows = m->hfield_nrow[field];
    shape.cols = m->hfield_ncol[field];
    shape.elevation = m->hfield_data + m->hfield_adr[field];
    if (shape.rows < 2 || shape.cols < 2) {
      throw Error(where + ": its height field has " + std::to_string(shape.rows) + " x " +
                  std::to_string(shape.cols) +
                  " points, which make no surface; give it at least 2 x 2, or keep it off "
                  "deformables (contype and conaffinity both even)");
    }
  }
  return shape;
}

void NearestEllipsoidPoint(const Eigen::Vector3d& radii, const Eigen::Vector3d& p,
                           Eigen::Vector3d& nearest, Eigen::Vector3d& normal) {
  // The nearest point x to p on the surface sum x_i^2 / a_i^2 = 1 has
  // x - p along the normal x_i / a_i^2: x_i = a_i^2 p_i / (a_i^2 + t), t
  // the root of g(t) = sum (a_i p_i / (a_i^2 + t))^2 = 1 with a_i^2 + t > 0
  // for every i (x on p's side of each plane of symmetry); for p inside,
  // t in (-a_min^2, 0], where g falls from infinity (if p_i != 0 on an axis
  // with a_i = a_min) to g(0) <= 1. In s = a_min^2 + t, which keeps its
  // precision near 0: s in (0, a_min^2], found by bisection. If p_i = 0 on
  // every smallest axis and g stays <= 1, the nearest points leave p's
  // plane: s = 0 and x on the first smallest axis from the surface's
  // equation (Eberly 2013, the degenerate cases).
  const Eigen::Vector3d q = p.cwiseAbs();  // (the positive octant; signs restored below)
  const double a_min = radii.minCoeff();
  Eigen::Vector3d shift;  // a_i^2 - a_min^2
  for (int i = 0; i < 3; ++i) shift[i] = radii[i] * radii[i] - a_min * a_min;
  auto g = [&](double s) {
    double sum = 0.0;
    for (int i = 0; i < 3; ++i) {
      if (q[i] == 0.0) continue;
      const double x = radii[i] * q[i] / (shift[i] + s);
      sum += x * x;
    }
    return sum;
  };
  bool on_smallest = false;  // p_i != 0 on an axis with a_i = a_min
  for (int i = 0; i < 3; ++i) on_smallest |= shift[i] == 0.0 && q[i] > 0.0;
  Eigen::Vector3d x;
  if (!on_smallest && g(0.0) <= 1.0) {
    int first = -1;
    double sum = 0.0;
    for (int i = 0; i < 3; ++i) {
      if (shift[i] == 0.0) {
        x[i] = 0.0;
        if (first < 0) first = i;
      } else {
        x[i] = radii[i] * radii[i] * q[i] / shift[i];
        sum += (x[i] / radii[i]) * (x[i] / radii[i]);
      }
    }
    x[first] = radii[first] * std::sqrt(std::max(0.0, 1.0 - sum));
  } else {
    double lo = 0.0, hi = a_min * a_min;  // g(lo) > 1 >= g(hi)
    for (int iteration = 0; iteration < 2200; ++iteration) {
      const double mid = 0.5 * (lo + hi);
      if (mid <= lo || mid >= hi) break;
      (g(mid) > 1.0 ? lo : hi) = mid;
    }
    for (int i = 0; i < 3; ++i) x[i] = radii[i] * radii[i] * q[i] / (shift[i] + hi);
  }
  for (int i = 0; i < 3; ++i) {
    if (p[i] < 0.0) x[i] = -x[i];
  }
  nearest = x;
  normal = x.cwiseQuotient(radii.cwiseProduct(radii)).normalized();
}

bool GeomPenetration(const GeomShape& shape, const Eigen::Vector3d& p, double& depth,
                     Eigen::Vector3d& direction) {
  const double* size = shape.size;
  switch (shape.type) {
    case mjGEOM_PLANE:
      depth = -p.z();
      direction = Eigen::Vector3d::UnitZ();
      return depth > 0.0;
    case mjGEOM_SPHERE: {
      const double r = p.norm();
      depth = size[0] - r;
      direction = r > 0.0 ? Eigen::Vector3d(p / r) : Eigen::Vector3d::UnitZ();
      return depth > 0.0;
    }
    case mjGEOM_CAPSULE: {
      const Eigen::Vector3d axis_point(0.0, 0.0, std::clamp(p.z(), -size[1], size[1]));
      const Eigen::Vector3d offset = p - axis_point;
      const double r = offset.norm();
      depth = size[0] - r;
      direction = r > 0.0 ? Eigen::Vector3d(offset / r) : Eigen::Vector3d::UnitX();
      return depth > 0.0;
    }
    case mjGEOM_ELLIPSOID: {
      const Eigen::Vector3d radii(size[0], size[1], size[2]);
      if (!(p.cwiseQuotient(radii).squaredNorm() < 1.0)) return false;
      Eigen::Vector3d nearest;
      NearestEllipsoidPoint(radii, p, nearest, direction);
      depth = (nearest - p).norm();
      return depth > 0.0;
    }
    case mjGEOM_BOX: {
      // inside: the nearest face
      const Eigen::Vector3d q = p.cwiseAbs() - Eigen::Vector3d(size[0], size[1], size[2]);
      int axis;
      depth = -q.maxCoeff(&axis);
      direction = Eigen::Vector3d::Unit(axis) * (p[axis] >= 0.0 ? 1.0 : -1.0);
      return depth > 0.0;
    }
    case mjGEOM_CYLINDER: {
      // inside: the nearer of the side and the cap
      const double radial = std::hypot(p.x(), p.y());
      const double side = size[0] - radial;
      const double cap = size[1] - std::abs(p.z());
      if (side < cap) {
        depth = side;
        direction = radial > 0.0 ? Eigen::Vector3d(p.x() / radial, p.y() / radial, 0.0)
                                 : Eigen::Vector3d::UnitX();
      } else {
        depth = cap;
        direction = Eigen::Vector3d(0.0, 0.0, p.z() >= 0.0 ? 1.0 : -1.0);
      }
      return depth > 0.0;
    }
    case mjGEOM_MESH:
      return MeshPenetration(shape, p, depth, direction);
    case mjGEOM_HFIELD:
      return HeightFieldPenetration(shape, p, depth, direction);
    default:
      return false;
  }
}

bool GeomEntry(const GeomShape& shape, const Eigen::Vector3d& outside,
               const Eigen::Vector3d& inside, double& t, Eigen::Vector3d& normal) {
  const double* size = shape.size;
  const Eigen::Vector3d& o = outside;
  const Eigen::Vector3d d = inside - outside;
  Interval line;
  switch (shape.type) {
    case mjGEOM_SPHERE:
      line = BallInterval(o, d, Eigen::Vector3d::Zero(), size[0], 0);
      break;
    case mjGEOM_ELLIPSOID: {
      // the unit ball in coordinates scaled by the radii (t is the same)
      const Eigen::Vector3d radii(size[0], size[1], size[2]);
      line = BallInterval(o.cwiseQuotient(radii), d.cwiseQuotient(radii), Eigen::Vector3d::Zero(),
                          1.0, 0);
      break;
    }
    case mjGEOM_CAPSULE: {
      // the union of a cylinder and two balls: the earliest entry of those
      // the line meets
      const Interval pieces[3] = {
          Intersect(RoundInterval(o, d, size[0], 0), SlabInterval(o, d, 2, size[1])),
          BallInterval(o, d, Eigen::Vector3d(0.0, 0.0, size[1]), size[0], 0),
          BallInterval(o, d, Eigen::Vector3d(0.0, 0.0, -size[1]), size[0], 0)};
      line.t_in = std::numeric_limits<double>::infinity();
      line.t_out = -std::numeric_limits<double>::infinity();
      for (const Interval& piece : pieces) {
        if (piece.t_in > piece.t_out || piece.t_out < 0.0 || piece.t_in > 1.0) continue;
        line.t_in = std::min(line.t_in, piece.t_in);
        line.t_out = std::max(line.t_out, piece.t_out);
      }
      line.face = 0;
      break;
    }
    case mjGEOM_BOX:
      line = Intersect(Intersect(SlabInterval(o, d, 0, size[0]), SlabInterval(o, d, 1, size[1])),
                       SlabInterval(o, d, 2, size[2]));
      break;
    case mjGEOM_CYLINDER:
      // (face 6: the round side; 4 and 5: the caps)
      line = Intersect(RoundInterval(o, d, size[0], 6), SlabInterval(o, d, 2, size[1]));
      break;
    case mjGEOM_MESH:
      for (size_t f = 0; f < shape.plane_normal.size(); ++f) {
        line = Intersect(line, HalfSpaceInterval(o, d, shape.plane_normal[f], shape.plane_offset[f],
                                                 static_cast<int>(f)));
      }
      break;
    default:  // (a plane or a height field: not sought)
      return false;
  }
  if (!(line.t_in <= line.t_out) || line.t_out < 0.0 || line.t_in > 1.0 || line.face < 0) {
    return false;
  }
  t = std::clamp(line.t_in, 0.0, 1.0);
  const Eigen::Vector3d x = o + t * d;
  switch (shape.type) {
    case mjGEOM_SPHERE:
      normal = x;
      break;
    case mjGEOM_ELLIPSOID:
      normal =
          x.cwiseQuotient(Eigen::Vector3d(size[0] * size[0], size[1] * size[1], size[2] * size[2]));
      break;
    case mjGEOM_CAPSULE:
      normal = x - Eigen::Vector3d(0.0, 0.0, std::clamp(x.z(), -size[1], size[1]));
      break;
    case mjGEOM_BOX:
      normal = SlabNormal(line.face);
      break;
    case mjGEOM_CYLINDER:
      normal = line.face == 6 ? Eigen::Vector3d(x.x(), x.y(), 0.0) : SlabNormal(line.face);
      break;
    default:  // mesh
      normal = shape.plane_normal[line.face];
      break;
  }
  const double length = normal.norm();
  if (!(length > 0.0)) return false;
  normal /= length;
  return true;
}

}  // namespace tetcosim
