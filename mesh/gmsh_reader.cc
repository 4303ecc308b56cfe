// Gmsh MSH 2.2 and 4.1, ASCII and binary (reference: the Gmsh manual, "MSH
// file format"). Tetrahedra (element type 4) are kept, and higher-order ones
// (types 11, 29, 30, 31) as linear ones, from their corner nodes, which Gmsh
// lists first; every other element type is skipped. Node tags may be
// non-contiguous and come in several blocks; physical tags are kept per
// tetrahedron (MSH 2.2: the first element tag; MSH 4.1: the first physical
// tag of the volume entity).

#include <cstdint>
#include <unordered_map>

#include "mesh/error.h"
#include "mesh/mesh_io.h"
#include "mesh/text_reader.h"

namespace tetcosim {
namespace {

constexpr int kGmshTet = 4;

// Whether a Gmsh element type is a tetrahedron: linear, or complete of order
// 2 to 5 (10, 20, 35 and 56 nodes)
bool IsGmshTet(long type) {
  return type == kGmshTet || type == 11 || type == 29 || type == 30 || type == 31;
}

// number of nodes of Gmsh element types (0: unknown)
int GmshNodesPerElement(long type) {
  static constexpr int kNodes[] = {0, 2,  3,  4,  4, 8,  6,  5,  3,  6,  9, 10, 27, 18, 14, 1,
                                   8, 20, 15, 13, 9, 10, 12, 15, 15, 21, 4, 5,  6,  20, 35, 56};
  if (type >= 0 && type < static_cast<long>(std::size(kNodes))) return kNodes[type];
  if (type == 92) return 64;
  if (type == 93) return 125;
  return 0;
}

class GmshReader {
 public:
  GmshReader(const std::string& path, std::string_view text) : scan_(path, text) {
    raw_.source = path;
  }

  RawMesh Read() {
    scan_.Expect("$MeshFormat");
    std::string_view version = scan_.Token("the MSH version");
    long file_type = scan_.Int("the file type (0 ASCII, 1 binary)");
    long data_size = scan_.Int("the data size");
    if (version == "2.2" || version == "2") {
      version2_ = true;
    } else if (version == "4.1") {
      version2_ = false;
    } else {
      scan_.Fail("MSH version " + std::string(version) +
                 " is not supported; tetcosim reads 2.2 and 4.1 (gmsh -format msh22 or msh41)");
    }
    if (file_type != 0 && file_type != 1) {
      scan_.Fail("file type " + std::to_string(file_type) + " is neither 0 (ASCII) nor 1 (binary)");
    }
    binary_ = file_type == 1;
    if (binary_ && data_size != 8) {
      scan_.Fail("binary data size " + std::to_string(data_size) + " is not supported (only 8)");
    }
    if (binary_) {
      scan_.SkipLine();
      scan_.set_binary(true);
      if (scan_.Binary<std::int32_t>("the byte-order check") != 1) {
        scan_.Fail("the file was written on a machine of other byte order; convert it to ASCII");
      }
      scan_.set_binary(false);
    }
    scan_.Expect("$EndMeshFormat");

    bool have_nodes = false;
    bool have_elements = false;
    while (!scan_.AtEnd()) {
      std::string_view section = scan_.Token("a section");
      if (section.empty() || section[0] != '$') {
        scan_.Fail("expected a section such as $Nodes, found '" +
                   std::string(section.substr(0, 40)) + "'");
      }
      if (section == "$Nodes") {
        version2_ ? ReadNodes2() : ReadNodes4();
        have_nodes = true;
      } else if (section == "$Elements") {
        if (!have_nodes) scan_.Fail("$Elements comes before $Nodes");
        version2_ ? ReadElements2() : ReadElements4();
        have_elements = true;
      } else if (section == "$Entities" && !version2_) {
        ReadEntities4();
      } else {
        std::string end = "$End" + std::string(section.substr(1));
        scan_.SkipLine();
        scan_.SkipPast(end);
      }
    }
    if (!have_nodes) scan_.Fail("the file has no $Nodes section");
    if (!have_elements) scan_.Fail("the file has no $Elements section");
    if (num_linearized_ > 0) raw_.warnings.push_back(LinearizedTetsWarning(num_linearized_));
    raw_.tets =
        Eigen::Map<const Tets>(tets_.data(), static_cast<Eigen::Index>(tets_.size() / 4), 4);
    return std::move(raw_);
  }

 private:
  void AddNode(long tag, double x, double y, double z) {
    int index = static_cast<int>(node_index_.size());
    if (!node_index_.emplace(tag, index).second) {
      scan_.Fail("node " + std::to_string(tag) + " is defined twice");
    }
    positions_.push_back(x);
    positions_.push_back(y);
    positions_.push_back(z);
    raw_.node_ids.push_back(tag);
    raw_.node_lines.push_back(binary_ ? 0 : scan_.line());
  }

  // a tetrahedron of element type `type` (IsGmshTet) from its first four
  // nodes, counting the higher-order ones
  void AddTet(long type, long tag, const long* nodes, int physical, long line) {
    num_linearized_ += type != kGmshTet;
    for (int i = 0; i < 4; ++i) {
      auto it = node_index_.find(nodes[i]);
      if (it == node_index_.end()) {
        std::string where = line > 0 ? " (line " + std::to_string(line) + ")" : "";
        scan_.Fail("element " + std::to_string(tag) + where + " refers to node " +
                   std::to_string(nodes[i]) + ", which the $Nodes section does not define");
      }
      tets_.push_back(it->second);
    }
    raw_.element_ids.push_back(tag);
    raw_.element_lines.push_back(line);
    raw_.tet_tags.push_back(physical);
  }

  long Count(std::string_view what) {
    long n = scan_.Int(what);
    if (n < 0) scan_.Fail(std::string(what) + " is negative");
    return n;
  }

  // MSH 2.2 ---------------------------------------------------------------
  void ReadNodes2() {
    long count = Count("the number of nodes");
    scan_.CheckCount(count, 8, "nodes");
    if (binary_) {
      scan_.SkipLine();
      scan_.set_binary(true);
      scan_.RequireBytes(static_cast<size_t>(count) * 28, "the nodes");
      for (long i = 0; i < count; ++i) {
        long tag = scan_.Binary<std::int32_t>("a node tag");
        double x = scan_.Binary<double>("x");
        double y = scan_.Binary<double>("y");
        double z = scan_.Binary<double>("z");
        AddNode(tag, x, y, z);
      }
      scan_.set_binary(false);
    } else {
      for (long i = 0; i < count; ++i) {
        long tag = scan_.Int("a node tag");
        double x = scan_.Double("x");
        double y = scan_.Double("y");
        double z = scan_.Double("z");
        AddNode(tag, x, y, z);
      }
    }
    scan_.Expect("$EndNodes");
    FinishNodes();
  }

  void ReadElements2() {
    long count = Count("the number of elements");
    if (binary_) {
      scan_.SkipLine();
      scan_.set_binary(true);
      long read = 0;
      while (read < count) {
        long type = scan_.Binary<std::int32_t>("an element block type");
        long follow = scan_.Binary<std::int32_t>("an element block size");
        long num_tags = scan_.Binary<std::int32_t>("an element block tag count");
        int nodes = GmshNodesPerElement(type);
        if (nodes == 0) scan_.Fail("unknown element type " + std::to_string(type));
        if (follow <= 0 || follow > count - read) {
          scan_.Fail("an element block holds " + std::to_string(follow) + " elements, where 1 to " +
                     std::to_string(count - read) + " remain of the " + std::to_string(count) +
                     " the section declares; the file is damaged");
        }
        if (num_tags < 0 || num_tags > 64) {
          scan_.Fail("an element block has " + std::to_string(num_tags) +
                     " tags an element, outside 0 to 64; the file is damaged");
        }
        scan_.RequireBytes(static_cast<size_t>(follow) * 4 * (1 + num_tags + nodes),
                           "an element block");
        for (long e = 0; e < follow; ++e) {
          long tag = scan_.Binary<std::int32_t>("an element tag");
          int physical = 0;
          for (long t = 0; t < num_tags; ++t) {
            int value = scan_.Binary<std::int32_t>("an element tag");
            if (t == 0) physical = value;
          }
          long ids[4] = {0, 0, 0, 0};
          for (int k = 0; k < nodes; ++k) {
            long id = scan_.Binary<std::int32_t>("an element node");
            if (k < 4) ids[k] = id;
          }
          if (IsGmshTet(type)) AddTet(type, tag, ids, physical, 0);
        }
        read += follow;
      }
      scan_.set_binary(false);
    } else {
      for (long e = 0; e < count; ++e) {
        long tag = scan_.Int("an element tag");
        long line = scan_.line();
        long type = scan_.Int("an element type");
        if (!IsGmshTet(type)) {
          scan_.SkipLine();
          continue;
        }
        long num_tags = Count("the number of element tags");
        int physical = 0;
        for (long t = 0; t < num_tags; ++t) {
          long value = scan_.Int("an element tag");
          if (t == 0) physical = static_cast<int>(value);
        }
        long ids[4];
        const int nodes = GmshNodesPerElement(type);
        for (int k = 0; k < nodes; ++k) {
          const long id = scan_.Int("a node of a tetrahedron");
          if (k < 4) ids[k] = id;
        }
        if (!scan_.TokenOnLine().empty()) {
          scan_.Fail("element " + std::to_string(tag) + " has more than the " +
                     std::to_string(nodes) + " nodes of its type (" + std::to_string(type) + ")");
        }
        AddTet(type, tag, ids, physical, line);
      }
    }
    scan_.Expect("$EndElements");
  }

  // MSH 4.1 ---------------------------------------------------------------
  // size_t values: binary 8 bytes, ASCII integers
  long Size(std::string_view what) {
    if (binary_) {
      std::uint64_t value = scan_.Binary<std::uint64_t>(what);
      if (value > (1ull << 40)) scan_.Fail(std::string(what) + " is implausibly large");
      return static_cast<long>(value);
    }
    return Count(what);
  }
  long Int4(std::string_view what) {
    return binary_ ? scan_.Binary<std::int32_t>(what) : scan_.Int(what);
  }
  double Double4(std::string_view what) {
    return binary_ ? scan_.Binary<double>(what) : scan_.Double(what);
  }

  void ReadEntities4() {
    if (binary_) {
      scan_.SkipLine();
      scan_.set_binary(true);
    }
    long counts[4];
    for (long& c : counts) c = Size("an entity count");
    for (int dim = 0; dim < 4; ++dim) {
      for (long e = 0; e < counts[dim]; ++e) {
        long tag = Int4("an entity tag");
        for (int k = 0; k < (dim == 0 ? 3 : 6); ++k) Double4("an entity coordinate");
        long num_physical = Size("a physical tag count");
        for (long p = 0; p < num_physical; ++p) {
          long physical = Int4("a physical tag");
          if (dim == 3 && p == 0) volume_physical_[tag] = static_cast<int>(physical);
        }
        if (dim > 0) {
          long num_bounding = Size("a bounding entity count");
          for (long b = 0; b < num_bounding; ++b) Int4("a bounding entity");
        }
      }
    }
    scan_.set_binary(false);
    scan_.Expect("$EndEntities");
  }

  void ReadNodes4() {
    if (binary_) {
      scan_.SkipLine();
      scan_.set_binary(true);
    }
    long num_blocks = Size("the number of node blocks");
    long num_nodes = Size("the number of nodes");
    Size("the smallest node tag");
    Size("the largest node tag");
    long total = 0;
    for (long b = 0; b < num_blocks; ++b) {
      long dim = Int4("an entity dimension");
      Int4("an entity tag");
      long parametric = Int4("the parametric flag");
      long count = Size("the number of nodes in a block");
      if (dim < 0 || dim > 3) {
        scan_.Fail("a node block's entity dimension is " + std::to_string(dim) +
                   ", outside 0 to 3; the file is damaged");
      }
      if (count > num_nodes - total) {  // (total <= num_nodes: no overflow)
        scan_.Fail("the node blocks hold more than the " + std::to_string(num_nodes) +
                   " nodes the section declares; the file is damaged");
      }
      scan_.CheckCount(count, binary_ ? 32 : 8, "nodes");
      int extra = parametric ? static_cast<int>(dim) : 0;
      std::vector<long> tags(static_cast<size_t>(count));
      for (long& tag : tags) tag = Size("a node tag");
      if (binary_) scan_.RequireBytes(static_cast<size_t>(count) * 8 * (3 + extra), "coordinates");
      for (long i = 0; i < count; ++i) {
        double x = Double4("x");
        double y = Double4("y");
        double z = Double4("z");
        for (int k = 0; k < extra; ++k) Double4("a parametric coordinate");
        AddNode(tags[static_cast<size_t>(i)], x, y, z);
      }
      total += count;
    }
    scan_.set_binary(false);
    scan_.Expect("$EndNodes");
    FinishNodes();
  }

  void ReadElements4() {
    if (binary_) {
      scan_.SkipLine();
      scan_.set_binary(true);
    }
    long num_blocks = Size("the number of element blocks");
    long num_elements = Size("the number of elements");
    Size("the smallest element tag");
    Size("the largest element tag");
    long total = 0;
    for (long b = 0; b < num_blocks; ++b) {
      Int4("an entity dimension");
      long entity = Int4("an entity tag");
      long type = Int4("an element type");
      long count = Size("the number of elements in a block");
      if (count > num_elements - total) {  // (total <= num_elements: no overflow)
        scan_.Fail("the element blocks hold more than the " + std::to_string(num_elements) +
                   " elements the section declares; the file is damaged");
      }
      int nodes = GmshNodesPerElement(type);
      if (nodes == 0) scan_.Fail("unknown element type " + std::to_string(type));
      auto physical_it = volume_physical_.find(entity);
      int physical = physical_it == volume_physical_.end() ? 0 : physical_it->second;
      if (binary_) {
        scan_.RequireBytes(static_cast<size_t>(count) * 8 * (1 + nodes), "an element block");
      }
      for (long e = 0; e < count; ++e) {
        long tag = Size("an element tag");
        long line = binary_ ? 0 : scan_.line();
        long ids[4] = {0, 0, 0, 0};
        for (int k = 0; k < nodes; ++k) {
          long id = Size("an element node");
          if (k < 4) ids[k] = id;
        }
        if (IsGmshTet(type)) AddTet(type, tag, ids, physical, line);
      }
      total += count;
    }
    scan_.set_binary(false);
    scan_.Expect("$EndElements");
  }

  void FinishNodes() {
    raw_.positions = Eigen::Map<const Positions>(
        positions_.data(), static_cast<Eigen::Index>(positions_.size() / 3), 3);
  }

  Scanner scan_;
  RawMesh raw_;
  bool version2_ = true;
  bool binary_ = false;
  std::vector<double> positions_;
  std::vector<int> tets_;
  long num_linearized_ = 0;  // higher-order tetrahedra read as linear
  std::unordered_map<long, int> node_index_;
  std::unordered_map<long, int> volume_physical_;
};

}  // namespace

RawMesh ReadGmsh(const std::string& path, std::string_view content) {
  return GmshReader(path, content).Read();
}

}  // namespace tetcosim
