#pragma once

// The penetration solver's surfaces (internal to collision/): the surface
// triangles of the objects a solve may find penetrated, at their current
// positions, which stage 2 (intersection edges against surfaces) and the
// closest features test, and those objects' current vertex normals, which
// stage 2 interpolates at a crossing.
//
// A solve: Place (which objects), then Make of each of them (on any thread,
// each object once), then AddRemaining and BuildTree for the objects whose
// closest features need them. Triangles are "in play" when an intersection
// edge can cross them: those that meet the object's search box (told by
// their corners' outcodes, no positions read). An object is made
// - small (at most kSmallSurface faces, the paper's 20-tet spheres): every
//   face in four-wide groups, which a query tests directly;
// - hashed: its faces in play as triangle entries, in a triangle hash of
//   its own (Teschner's, cell size the solver's), the few too large to
//   hash listed (and in a box tree when they are many);
// - fully: every face (closest method), without hash or normals.
// Allocation-free once warm: storage only grows.

#include <Eigen/Core>
#include <cstdint>
#include <span>
#include <vector>

#include "collision/box_tree.h"
#include "collision/collision_object.h"
#include "collision/kept_object.h"
#include "collision/spatial_hash.h"
#include "mesh/tet_mesh.h"

namespace tetcosim {

class Surfaces {
 public:
  // a surface triangle in its object's triangle hash (or list): what a
  // query tests first, and its geometry (kept apart, read only for the few
  // triangles whose box a query overlaps)
  struct Entry {
    Eigen::Vector3d lo, hi;  // bounding box (InflatedBounds of the corners)
    int object;
    int face;  // index into the object's surface
  };
  struct Geometry {
    Eigen::Vector3d corner[3];         // current positions
    Eigen::Vector3d edge[2];           // corner[1] - corner[0], corner[2] - corner[0]
    double edge_lengths;               // |edge[0]| |edge[1]|
    Eigen::Vector3i cell_lo, cell_hi;  // the cells the box covers
  };
  // small objects' triangles, four to a group (stage 2 tests four at a
  // time): the four faces' boxes and geometry by coordinate, 512 bytes in a
  // row, so that a small body's faces are read front to back (in a pile of
  // 1200 spheres, arrays by coordinate spread each body's over 16 streams
  // that did not stay in the core's cache). An object's faces start a
  // group; lanes past its last face have NaN boxes, which overlap nothing.
  struct alignas(64) SmallGroup {
    double lo[3][4], hi[3][4];        // the box
    double corner[3][4];              // Geometry's corner[0]
    double edge0[3][4], edge1[3][4];  // and edges
    double edge_lengths[4];
  };
  // a hashed object's entries' boxes in its hash's bucket order (hash
  // entry e: entry hash.items()[e]), by coordinate and padded by
  // kSimdPadding NaN, so that a query tests a bucket's boxes four at a time
  struct BucketBoxes {
    std::vector<double> lo[3], hi[3];
  };
  // Per object that is not small: its entries in a hash of its own, which
  // the thread that makes the object builds (a shared table would be filled
  // by one thread: on two cubes that was a tenth of the solve, serial), the
  // entries too large to hash, and the box trees. On cache lines of their
  // own: threads fill neighbouring objects' tables at once.
  struct alignas(64) Table {
    SpatialHash hash;
    BucketBoxes boxes;
    std::vector<int> large;  // entries over more than kMaxTriangleCells cells
    // stage 2: a box tree over the large entries when they are many (item
    // i: entry large[i]), else empty
    BoxTree large_tree;
    std::vector<Eigen::Vector3d> large_lo, large_hi;
    // closest features (BuildTree): a box tree over all the object's
    // entries (item i: entry tree_entry[i], box [tree_lo[i], tree_hi[i]])
    BoxTree tree;
    std::vector<Eigen::Vector3d> tree_lo, tree_hi;
    std::vector<int> tree_entry;
  };

  // Objects with at most this many surface triangles (the paper's 20-tet
  // spheres) are small: a query tests their few triangles directly, which
  // is cheaper than walking the cells of a segment or a box tree.
  static constexpr int kSmallSurface = 48;
  // Triangles whose bounding box covers more than this many cells are not
  // hashed but listed, and tested against every query (large faces of
  // coarse rigid proxies).
  static constexpr long kMaxTriangleCells = 64;
  // Stage 2 finds the listed triangles that a segment meets through a box
  // tree when an object has more than this many, else by testing each (a
  // coarse floor mesh under fine bodies has thousands).
  static constexpr int kMaxLargeListed = 16;

  // Begins a solve's surfaces: those of the objects in `list` (of
  // `objects`, ascending), each given a range of entries the size of its
  // surface. With `full`, every face of an object that is not kept is
  // made, else its faces in play; with `hash_and_normals` off (closest
  // features only), no hash and no normals. cell_size: the solver's, in
  // metres. Returns the number of entries.
  int Place(std::span<const CollisionObject> objects, std::span<const int> list,
            std::span<const KeptObject> kept, bool full, bool hash_and_normals, double cell_size);
  // Makes object o of the list: its entries (or groups), its hash and its
  // current vertex normals (of every vertex where most of the surface is in
  // play, else of the entries' vertices). outcode: the sides of o's search
  // box each of its vertices lies beyond (#V of o; 0: inside). faces: the
  // calling thread's scratch. Objects may be made on several threads at
  // once, each once.
  void Make(std::span<const CollisionObject> objects, int o, const KeptObject& kept,
            const std::uint8_t* outcode, std::vector<int>& faces);
  // Adds entries for the faces of object b that Make left out (for closest
  // features, which may lie outside the search box), once per solve, on
  // one thread; nothing for a kept object, whose tree of all faces is kept.
  void AddRemaining(std::span<const CollisionObject> objects, int b, const KeptObject& kept,
                    const std::uint8_t* outcode);
  // Object b's box tree over all its entries (closest features).
  void BuildTree(int b);

  // The entries, object by object: each object's range is the size of its
  // surface, its entries in play at the start; those added by AddRemaining
  // come after every object's range. A small object's range is only
  // numbered: entry begin + f is its face f, kept in its groups alone (an
  // entry and geometry, 208 bytes a triangle, were written every solve and
  // read almost never).
  int num_entries() const { return static_cast<int>(entries_.size()); }
  const Entry& entry(int index) const { return entries_[index]; }
  const Geometry& geometry(int index) const { return geometry_[index]; }
  // object o's entries in play [entry_begin, entry_end), and those added
  // by AddRemaining [rest_begin, rest_end)
  int entry_begin(int o) const { return entry_begin_[o]; }
  int entry_end(int o) const { return entry_end_[o]; }
  int rest_begin(int o) const { return rest_begin_[o]; }
  int rest_end(int o) const { return rest_end_[o]; }
  bool small(int o) const { return small_[o] != 0; }
  // a small object's groups (its face f: lane f % 4 of group f / 4)
  const SmallGroup* groups(int o) const { return &groups_[small_begin_[o]]; }
  const Table& table(int o) const { return tables_[o]; }
  // the thread that made object o (Make)
  int builder(int o) const { return builder_[o]; }
  // object o's current vertex normals (#V x 3; those of the entries'
  // vertices at least)
  const Positions& normals(int o) const { return normals_[o]; }

 private:
  // entry `index` into its object's hash, or its list of large entries
  void Insert(int index);
  // sorts object o's hash by bucket and lays out its boxes in that order
  void BuildHash(int o);
  // the entry and geometry of face f of an object at its current position
  void MakeTriangle(std::span<const CollisionObject> objects, int object, int f, Entry& entry,
                    Geometry& geometry) const;

  double cell_size_ = 1.0;
  double inverse_cell_size_ = 1.0;
  bool hash_and_normals_ = true;
  std::vector<Entry> entries_;
  std::vector<Geometry> geometry_;  // per entry
  std::vector<SmallGroup> groups_;  // small objects' faces, by group
  std::vector<Table> tables_;       // #objects
  // #objects (of those in the list only: what this solve placed)
  std::vector<int> small_begin_;  // its first group in groups_
  std::vector<int> builder_;
  std::vector<char> fully_;  // every face made
  std::vector<char> small_;  // surface tested directly, not hashed
  std::vector<int> entry_begin_, entry_end_;
  std::vector<int> rest_begin_, rest_end_;
  std::vector<Positions> normals_;
  // per object and vertex, the round in which its normal was computed
  // (Make computes a vertex's once, with those of few faces in play)
  std::vector<std::vector<std::uint32_t>> normal_stamp_;
  std::uint32_t normal_round_ = 0;
};

}  // namespace tetcosim
