// Stage 4 of the penetration solver: depths and directions propagated from
// the border points to the inner colliding points, layer by layer.

#include "collision/penetration.h"

#include <omp.h>

#include <algorithm>
#include <cmath>
#include <span>

#include "collision/geometry.h"
#include "collision/penetration_internal.h"
#include "mesh/parallel_for.h"

namespace tetcosim {
namespace {

// Stage 4 computes a layer on several threads from this many points per
// thread. A point takes about 40 ns; on two threads the layers of the 70%
// cubes (up to a few hundred points) took longer together than on one,
// with 32 (15.1-15.7 against 12.3 us; 25.7 when the cores were far apart,
// build/bench/two_cores: 450-550 ns round trip), and 12.7-12.9 us with 256.
constexpr int kMinLayerPointsPerThread = 256;

}  // namespace

// stage 4: propagation to inner points, each layer from earlier layers only
void PenetrationSolver::Propagate(std::span<const CollisionObject> objects) {
  Clock::time_point start = Clock::now();
  const int num_threads = std::max(1, options_.num_threads);
  constexpr int kInNextLayer = -2;
  if (static_cast<int>(thread_scratch_.size()) < num_threads) thread_scratch_.resize(num_threads);
  // the next layer: the points without a value next to a point with one
  // (the first from the border points; later ones from the candidates the
  // layer's computation listed), in index order
  auto add_to_next_layer = [&](int h) {
    if (layer_[h] != -1) return;
    layer_[h] = kInNextLayer;
    next_frontier_.push_back(h);
  };
  // the first layer: the neighbours of border points that stage 2 listed
  next_frontier_.clear();
  for (int i = 0; i < num_threads; ++i) {
    for (int h : thread_scratch_[i].candidates) add_to_next_layer(h);
  }
  const double coincident = 1e-9 * length_scale_;
  int layer = 0;
  while (!next_frontier_.empty()) {
    ++layer;
    std::sort(next_frontier_.begin(), next_frontier_.end());
    const int layer_size = static_cast<int>(next_frontier_.size());
    const int threads = ThreadsFor(num_threads, layer_size, kMinLayerPointsPerThread);
    // (every thread's emptied, with room for all of the last layer's
    // candidates, and for those of a point whose directions cancel:
    // penetration_internal.h)
    ClearForAnyShare(std::span<ThreadScratch>(thread_scratch_), &ThreadScratch::candidates,
                     max_degree_);
    // each point of the layer from its neighbours of earlier layers; a
    // point that gets a value lists its neighbours without one (those of
    // this layer too: they stay without one if their directions cancel)
    ParallelFor(threads, 0, layer_size, [&](int i) {
      const int h = next_frontier_[i];
      const int g = colliding_.hits()[h].vertex;
      const int a = vertices_.object[g];
      const int v = g - vertices_.offset[a];
      const TetMesh& mesh = *objects[a].mesh;
      const Eigen::Vector3d p = Position(g);
      PropagatedPointSums sums(coincident);
      std::vector<int>& candidates = thread_scratch_[omp_get_thread_num()].candidates;
      const size_t num_listed = candidates.size();
      for (int n = mesh.adjacency_offsets()[v]; n < mesh.adjacency_offsets()[v + 1]; ++n) {
        const int j_global = vertices_.offset[a] + mesh.adjacency()[n];
        const int j = FindHit(j_global, colliding_.hits()[h].penetrated);
        if (j < 0) continue;
        if (layer_[j] < 0) {  // a later layer, or this one
          candidates.push_back(j);
          continue;
        }
        sums.Add(Position(j_global) - p, depth_[j], direction_[j]);
      }
      source_[h] = DepthSource::kPropagated;
      if (!sums.Result(depth_[h], direction_[h])) {
        // (directions that cancel leave the point without a value)
        direction_[h] = Eigen::Vector3d::Zero();
        candidates.resize(num_listed);
      }
    });
    for (int h : next_frontier_) {
      layer_[h] = direction_[h].squaredNorm() > 0.0 ? layer : -1;
    }
    next_frontier_.clear();
    for (int i = 0; i < threads; ++i) {
      for (int h : thread_scratch_[i].candidates) add_to_next_layer(h);
    }
  }
  stats_.layers = layer;
  timings_.propagate += SecondsSince(start);
}

}  // namespace tetcosim
