// TetGen .node and .ele files (reference: the TetGen manual, section 5.2).
// .node: "<#points> <dim=3> <#attributes> <#boundary markers (0|1)>", then
//        "<index> <x> <y> <z> [attributes] [marker]" per point.
// .ele:  "<#tets> <nodes per tet (4|10)> <#region attributes (0|1)>", then
//        "<index> <n1> <n2> <n3> <n4> [more nodes] [attribute]" per tet.
// '#' starts a comment. Indices are 0- or 1-based, following the first point.

#include <cmath>
#include <cstdio>
#include <unordered_map>

#include "mesh/error.h"
#include "mesh/mesh_io.h"
#include "mesh/text_reader.h"

namespace tetcosim {

RawMesh ReadTetGen(const std::string& node_path, std::string_view node_content,
                   const std::string& ele_path, std::string_view ele_content) {
  RawMesh raw;
  raw.source = ele_path;

  Scanner nodes(node_path, node_content, '#');
  long num_points = nodes.Int("the number of points");
  long dim = nodes.Int("the dimension");
  long num_attributes = nodes.Int("the number of point attributes");
  long num_markers = nodes.Int("the number of boundary markers");
  if (dim != 3) nodes.Fail("dimension " + std::to_string(dim) + " is not 3");
  if (num_attributes < 0) {
    nodes.Fail("the number of point attributes is " + std::to_string(num_attributes) +
               "; give 0 or more");
  }
  nodes.CheckCount(num_attributes, 2, "point attributes");  // (each point's, at least)
  if (num_markers < 0 || num_markers > 1) {
    nodes.Fail("the number of boundary markers is " + std::to_string(num_markers) +
               "; TetGen writes 0 or 1");
  }
  nodes.CheckCount(num_points, 8, "points");
  raw.positions.resize(num_points, 3);
  raw.node_ids.resize(static_cast<size_t>(num_points));
  raw.node_lines.resize(static_cast<size_t>(num_points));
  std::unordered_map<long, int> index_of;
  for (long i = 0; i < num_points; ++i) {
    long id = nodes.Int("a point index");
    raw.node_lines[static_cast<size_t>(i)] = nodes.line();
    for (int k = 0; k < 3; ++k) raw.positions(i, k) = nodes.Double("a coordinate");
    for (long a = 0; a < num_attributes + num_markers; ++a) nodes.Double("a point attribute");
    if (!index_of.emplace(id, static_cast<int>(i)).second) {
      nodes.Fail("point " + std::to_string(id) + " is defined twice");
    }
    raw.node_ids[static_cast<size_t>(i)] = id;
  }

  Scanner elements(ele_path, ele_content, '#');
  long num_tets = elements.Int("the number of tetrahedra");
  long nodes_per_tet = elements.Int("the number of nodes per tetrahedron");
  long num_region = elements.Int("the number of region attributes");
  elements.CheckCount(num_tets, 10, "tetrahedra");
  if (nodes_per_tet != 4 && nodes_per_tet != 10) {
    elements.Fail("nodes per tetrahedron is " + std::to_string(nodes_per_tet) + ", not 4 or 10");
  }
  if (num_region < 0) elements.Fail("the number of region attributes is negative");
  elements.CheckCount(num_region, 2, "region attributes");  // (each tetrahedron's, at least)
  raw.tets.resize(num_tets, 4);
  raw.element_ids.resize(static_cast<size_t>(num_tets));
  raw.element_lines.resize(static_cast<size_t>(num_tets));
  if (num_region > 0) raw.tet_tags.resize(static_cast<size_t>(num_tets));
  for (long t = 0; t < num_tets; ++t) {
    long id = elements.Int("a tetrahedron index");
    raw.element_ids[static_cast<size_t>(t)] = id;
    raw.element_lines[static_cast<size_t>(t)] = elements.line();
    for (long k = 0; k < nodes_per_tet; ++k) {
      long node = elements.Int("a node index");
      if (k >= 4) continue;
      auto it = index_of.find(node);
      if (it == index_of.end()) {
        elements.Fail("tetrahedron " + std::to_string(id) + " refers to point " +
                      std::to_string(node) + ", which " + node_path + " does not define");
      }
      raw.tets(t, k) = it->second;
    }
    for (long a = 0; a < num_region; ++a) {
      double attribute = elements.Double("a region attribute");
      if (a > 0) continue;
      // (the tag: the first attribute, a region number, truncated to an int)
      if (!(std::abs(attribute) < 2147483648.0)) {
        char value[32];
        std::snprintf(value, sizeof(value), "%g", attribute);
        elements.Fail("tetrahedron " + std::to_string(id) + "'s region attribute is " + value +
                      "; a region number must be finite and within the range of an int");
      }
      raw.tet_tags[static_cast<size_t>(t)] = static_cast<int>(attribute);
    }
  }
  if (nodes_per_tet == 10 && num_tets > 0) raw.warnings.push_back(LinearizedTetsWarning(num_tets));
  return raw;
}

}  // namespace tetcosim
