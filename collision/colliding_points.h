#pragma once

// Stage 1 of the penetration solver (internal to collision/): the colliding
// points, every vertex of an object inside a tetrahedron of another (or of
// its own, with self-collision, but not one of the vertex's own), through
// the spatial hash of the vertices (Teschner et al. 2003).
//
// A solve: Begin, then Find, or its parts in order (for a caller that
// overlaps them with other work: the solver makes surfaces on other threads
// while one thread builds the vertex hash):
//   BeginVertexHash; ClassifyVertices over every vertex range;
//   ClassifyKeptVertices; BuildVertexHash; BeginSearch; SearchChunk of
//   every searched chunk (any thread); SearchLargeTets; MergeHits.
// Pass 1 classifies every vertex against its object's search box (an
// outcode: the sides it lies beyond) and hashes those inside by cell; pass
// 2 takes the tetrahedra in chunks of kChunkTets along each object's
// spatial order, looks up the cells of a chunk's union of boxes once and
// tests the vertices found there against each tetrahedron's box, then its
// barycentric coordinates (docs/collision.md, stage 1). A vertex inside
// several tetrahedra of one object keeps the one it is deepest in. The
// hits are the same, in the same order, whatever the number of threads.
// Allocation-free once warm: storage only grows.

#include <Eigen/Core>
#include <array>
#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "collision/broad_phase.h"
#include "collision/collision_object.h"
#include "collision/geometry.h"
#include "collision/kept_object.h"
#include "collision/spatial_hash.h"
#include "mesh/tet_mesh.h"

namespace tetcosim {

// A solve's vertices, numbered object after object (global numbers).
struct GlobalVertices {
  std::vector<int> offset;  // #objects + 1: the global number of each object's first vertex
  std::vector<int> object;  // per global vertex: its object
  std::vector<int> object_filled_for;       // the offsets that `object` was filled for
  std::vector<const Positions*> positions;  // #objects: current positions (world, metres)

  Eigen::Vector3d Position(int g) const {
    const int o = object[g];
    return positions[o]->row(g - offset[o]).transpose();
  }
};

class CollidingPoints {
 public:
  // a colliding point: global vertex inside object `penetrated`
  struct Hit {
    int vertex;                   // global vertex number
    int penetrated;               // object B
    int tet;                      // B's tetrahedron (B's numbering)
    Eigen::Vector4d barycentric;  // of the vertex in it
    bool operator<(const Hit& o) const {
      return vertex != o.vertex           ? vertex < o.vertex
             : penetrated != o.penetrated ? penetrated < o.penetrated
                                          : tet < o.tet;
    }
  };

  // Begins a solve: the objects, their vertices, what is kept of the
  // fixed and framed ones (active this solve if any_kept; their chunks to
  // search, and later their classified vertices, are written there), the
  // broad phase's partners and search boxes, and the cell size (metres).
  // They must stay as they are until the solve's stage 1 is done.
  void Begin(std::span<const CollisionObject> objects, const GlobalVertices& vertices,
             std::span<KeptObject> kept, bool any_kept, const BroadPhase& broad_phase,
             double cell_size);
  // All of stage 1 on up to num_threads threads; the seconds spent hashing
  // and searching are added to hash_seconds and inside_seconds.
  void Find(int num_threads, double& hash_seconds, double& inside_seconds);

  // stage 1's parts (see above)
  void BeginVertexHash();
  void ClassifyVertices(int begin_vertex, int end_vertex);  // (global numbers; not kept objects')
  // kept objects' vertices: only those of the searched chunks (and loose
  // ones) get their outcode and cell; the others are beyond every side
  void ClassifyKeptVertices();
  void BuildVertexHash(int num_threads);
  // Returns the number of chunks to search (0 if every object is rigid).
  int BeginSearch(int num_threads);
  // Whether the vertex hash holds any vertex (after BuildVertexHash; if
  // not, no chunk needs searching).
  bool any_hashed() const { return hash_.num_items() > 0; }
  void SearchChunk(int searched);  // the searched-th chunk to search (any thread)
  // the large tetrahedra the chunks met, against the vertices in their
  // boxes: through a coarse grid when they are many, else each against
  // every hashed vertex
  void SearchLargeTets(int num_threads);
  void MergeHits();

  // Stage 1's chunks of tetrahedra in all (before leaving out those far
  // from every partner).
  int num_chunks() const { return chunk_offset_.back(); }
  // The hits, sorted by (vertex, penetrated), one per (vertex, object).
  const std::vector<Hit>& hits() const { return hits_; }
  // The hit of a global vertex in object `penetrated`, or -1. (Inline:
  // stages 2 and 4 call it for every neighbour of a point.)
  int FindHit(int vertex, int penetrated) const {
    const auto [begin, end] = hit_range_[vertex];
    for (int h = begin; h < end; ++h) {
      if (hits_[h].penetrated == penetrated) return h;
    }
    return -1;
  }
  // Object o's vertices' outcodes (#V of o): the sides of o's search box
  // each lies beyond, 0 inside (Surfaces reads them).
  const std::uint8_t* outcodes(int o) const {
    return vertex_outcode_.data() + vertices_->offset[o];
  }
  // Vertex-in-tetrahedron tests made (PenetrationStats::tet_tests).
  std::int64_t tet_tests() const { return tet_tests_; }

 private:
  // the vertices in the vertex hash, in its entry (bucket) order, by
  // coordinate so that a tetrahedron tests four candidates at once against
  // its box (padded by kSimdPadding)
  struct HashedVertices {
    std::vector<double> x, y, z;  // position
    std::vector<int> vertex;      // global vertex number
    std::vector<int> object;      // its object
    // every array to n entries (a chunk's gathered candidates: their size
    // is their room, kSimdPadding included)
    void Resize(std::size_t n) {
      for (std::vector<double>* values : {&x, &y, &z}) values->resize(n);
      vertex.resize(n);
      object.resize(n);
    }
  };
  // a tetrahedron of object B being searched: its corners and box, and its
  // barycentric coordinates once a vertex in its box needs them
  struct SearchedTet {
    int t;
    Eigen::Vector3d corner[4];
    Eigen::Vector3d lo, hi;
    TetCoordinates coordinates;
    bool have_coordinates;
  };
  // a tetrahedron whose box covers more than kMaxTetCells cells, searched
  // after the chunks (SearchLargeTets): its object and number, whose
  // vertices it tests (partner: an index of BroadPhase::partner, or -1 for
  // every partner's), and its box within the region where those can be
  struct LargeTet {
    int object;
    int tet;
    int partner;
    Eigen::Vector3d lo, hi;
  };
  // BuildVertexHash: blocks of vertices to hash, each [begin, end) of the
  // global vertices, or `kept`'s list of vertices in its search box (its
  // first `end`)
  struct VertexBlock {
    int begin, end;
    int kept;  // the kept object, or -1
  };
  // What one thread writes, on cache lines of its own: in a plain array,
  // neighbouring threads' vector headers share a line, and every push_back
  // (which moves the end pointer) would take that line away from the other
  // core (measured: stage 1 on two threads did 24% more work in all than
  // on one).
  struct alignas(64) ThreadScratch {
    std::vector<Hit> hits;             // what the thread found
    HashedVertices gathered;           // a chunk's candidates (vertex: the entry in hashed_)
    std::vector<LargeTet> large_tets;  // met in the chunks, searched after
    std::int64_t tet_tests = 0;
  };

  // Whether entry e of hashed_, a vertex of object a, lies inside `tet` of
  // object b; if so, adds the hit to the thread's hits.
  void TestVertexInTet(const TetMesh& mesh_b, int b, SearchedTet& tet, int e, int a,
                       ThreadScratch& scratch) const;
  void BuildCoarseVertexHash(int num_threads);
  // the chunk of the i-th search
  int SearchedChunk(int i) const { return any_kept_ ? search_chunks_[i] : i; }
  // the grid cell of p
  Eigen::Vector3i Cell(const Eigen::Vector3d& p) const { return GridCell(p, inverse_cell_size_); }

  // the solve's (Begin)
  std::span<const CollisionObject> objects_;
  const GlobalVertices* vertices_ = nullptr;
  std::span<KeptObject> kept_;
  bool any_kept_ = false;
  const BroadPhase* broad_phase_ = nullptr;
  double cell_size_ = 1.0;
  double inverse_cell_size_ = 1.0;

  std::vector<int> chunk_offset_;  // #objects + 1: global number of each object's first chunk
  // with any_kept_: the chunks to search (every chunk of an object that is
  // not kept, a kept one's chunks that meet its search box), ascending
  std::vector<int> search_chunks_;
  SpatialHash hash_;                          // the vertices
  std::vector<Eigen::Vector3i> vertex_cell_;  // #global vertices (those hashed)
  std::vector<VertexBlock> vertex_blocks_;
  std::vector<int> block_insertion_;          // each block's first insertion
  std::vector<std::uint8_t> vertex_outcode_;  // #global vertices: the sides of its object's
                                              // search box it lies beyond (0: hashed)
  HashedVertices hashed_;
  // the large tetrahedra, when many: hashed_'s entries again, in a grid
  // kCoarseCellFactor times coarser (a tet of 20^3 cells looks up 27 cells
  // of it), their positions in its bucket order (vertex: the entry in
  // hashed_)
  SpatialHash coarse_hash_;
  HashedVertices coarse_;
  std::vector<LargeTet> large_tets_;           // every thread's, for SearchLargeTets
  std::vector<ThreadScratch> thread_scratch_;  // #threads
  std::vector<Hit> hits_;                      // sorted by (vertex, penetrated)
  std::vector<std::array<int, 2>> hit_range_;  // #global vertices: its hits [begin, end)
  std::vector<int> hit_place_;                 // MergeHits' counting sort: #global vertices + 1
  std::int64_t tet_tests_ = 0;
};

}  // namespace tetcosim
