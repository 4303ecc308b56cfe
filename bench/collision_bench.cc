// Penetration solver cost, per stage and per colliding point, for the
// scenes the collision issue names: two cubes of 1250 tetrahedra at several
// overlaps, 120 paper spheres (20 tetrahedra each) packed with many
// contacts (and piles of 240 to 9600), a scene of about 100k tetrahedra,
// and 1 to 10 copies of the two-cube scene (cost against the number of
// colliding points); a coarse box's corner in a fine ball (edges hundreds
// of cells long), a ball enclosed in a block (the closest-feature
// fallback), fine cubes on a coarse slab (triangles too large to hash)
// and on a less coarse one (tetrahedra too large to search cell by cell),
// and one small ball on rigid slabs of 7,500 to 480,000 tetrahedra (what a
// large body costs beyond its contacts: still, fixed, turning, and turning
// with its frame); and the broad phase alone on piles of up to 153,600
// boxes (BM_BroadPhasePile). The scenes also run moving
// (BM_TwoCubesMoving, ...: each solve the next time step, as in a
// simulation).
//
// Counters: colliding points and intersection edges (stage 2) per solve
// (the mean over the solves of a moving scene), microseconds
// per colliding point (from the solver's own wall-clock timing of Solve),
// the same for resolving the points found (all but stage 1), milliseconds
// per stage, and the work behind a point (a solve's counts repeat
// exactly): vertex-in-tetrahedron tests and intersection edges per point,
// segment-triangle tests per edge.
// Arguments: (scene parameter, method 0 consistent / 1 closest, threads).

#include <benchmark/benchmark.h>

#include <Eigen/Geometry>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "collision/broad_phase.h"
#include "collision/penetration.h"
#include "mesh/generators.h"

namespace tetcosim {
namespace {

// A moving scene's time steps: kMovingSteps steps of 1 ms, solved forth and
// back (0, 1, ..., 15, 14, ..., 1, 0, ...: every solve a step away from the
// last, as in a simulation).
constexpr int kMovingSteps = 16;
constexpr double kMovingDt = 1e-3;

struct Scene {
  std::vector<std::unique_ptr<TetMesh>> meshes;
  std::vector<std::unique_ptr<Positions>> positions;
  std::vector<CollisionObject> objects;
  // moving scenes only (MakeMoving): each object's positions at step 0 and
  // its velocity, its angular velocity about z through the origin (rad/s),
  // and the rigid motion from step 0 to the step shown (for objects given
  // it as their CollisionObject::frame)
  std::vector<Positions> start;
  std::vector<Eigen::RowVector3d> velocity;
  std::vector<double> spin;
  std::vector<RigidFrame> frames;

  void Add(const TetMesh& mesh, const Eigen::Vector3d& translation, double angle = 0.0) {
    // meshes of the same shape are shared, as scenes do
    positions.push_back(std::make_unique<Positions>(mesh.positions()));
    Eigen::Matrix3d rotation =
        Eigen::AngleAxisd(angle, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
    for (Eigen::Index v = 0; v < positions.back()->rows(); ++v) {
      positions.back()->row(v) =
          (rotation * mesh.positions().row(v).transpose() + translation).transpose();
    }
    objects.push_back({&mesh, positions.back().get(), false, false});
  }
  const TetMesh& Mesh(const std::string& spec) {
    meshes.push_back(std::make_unique<TetMesh>(TetMesh::Build(MakeShape(spec))));
    return *meshes.back();
  }

  // Gives every object a velocity of up to `speed` (m/s) along each axis,
  // drawn from a seeded generator.
  void MakeMoving(double speed) {
    std::mt19937 rng(1998);
    std::uniform_real_distribution<double> component(-speed, speed);
    for (const std::unique_ptr<Positions>& x : positions) {
      start.push_back(*x);
      velocity.emplace_back(component(rng), component(rng), component(rng));
    }
    spin.assign(positions.size(), 0.0);
    frames.resize(positions.size());  // (not resized again: objects point into it)
  }
  bool moving() const { return !start.empty(); }
  // Moves the objects to step `step` (a moving scene), in place, as a
  // simulation's step does; the frames get the box of the positions written,
  // as the bridge gives a moving body's proxy.
  void ShowStep(int step) {
    const double t = kMovingDt * step;
    for (size_t o = 0; o < positions.size(); ++o) {
      RigidFrame& frame = frames[o];
      frame.rotation = Eigen::AngleAxisd(spin[o] * t, Eigen::Vector3d::UnitZ()).toRotationMatrix();
      frame.translation = velocity[o].transpose() * t;
      const Eigen::RowVector3d shift = velocity[o] * t;
      Positions& x = *positions[o];
      PositionBounds bounds;
      for (Eigen::Index v = 0; v < x.rows(); ++v) {
        x.row(v) = start[o].row(v) * frame.rotation.transpose() + shift;
        bounds.Add(x.row(v).transpose());
      }
      frame.bounds = bounds;
    }
  }
};

// The step a moving scene's `solve`-th solve shows (forth and back).
int PingPong(long solve) {
  const int k = static_cast<int>(solve % (2 * (kMovingSteps - 1)));
  return k < kMovingSteps ? k : 2 * (kMovingSteps - 1) - k;
}

// How fast the objects of the moving scenes go, per axis: a pile settling,
// two bodies pressed together (m/s).
constexpr double kMovingSpeed = 0.2;

// the paper's cube: 1250 tetrahedra (5 x 5 x 10 cells, 5 tets each), 10 cm
constexpr const char* kCube = "box:size=0.05,0.05,0.05:res=5,5,10:split=5";

// `copies` pairs of cubes side by side, each pair overlapping by `overlap`
// of the width along x (and offset a little in y and z)
void AddCubePairs(Scene& scene, double overlap, int copies) {
  const TetMesh& cube = scene.Mesh(kCube);
  for (int c = 0; c < copies; ++c) {
    Eigen::Vector3d base(0.0, 0.3 * c, 0.0);
    scene.Add(cube, base);
    scene.Add(cube, base + Eigen::Vector3d(0.1 * (1.0 - overlap), 0.011, -0.007), 0.1);
  }
}

// per stage: broad phase and vertex hash, vertex-in-tetrahedron (stage 1),
// surfaces (normals and triangle hash), crossings and border points (stages
// 2 and 3), propagation (4), closest features
constexpr int kStages = 6;

// What the timed solves found and did, summed over them
struct Work {
  double colliding = 0.0;       // colliding points (results)
  double edges = 0.0;           // intersection edges
  double tet_tests = 0.0;       // vertex-in-tetrahedron tests (stage 1)
  double triangle_tests = 0.0;  // segment-triangle tests (stage 2)
};

void Report(benchmark::State& state, double total, const double stages[kStages], const Work& work) {
  const double iterations = static_cast<double>(state.iterations());
  const double colliding = work.colliding;
  state.counters["colliding"] = colliding / iterations;  // per solve
  state.counters["edges"] = work.edges / iterations;
  // the work behind a point: what the time per point is made of (a solve's
  // counts are the same on every run and thread count)
  state.counters["tet_tests_per_point"] = colliding > 0 ? work.tet_tests / colliding : 0.0;
  state.counters["edges_per_point"] = colliding > 0 ? work.edges / colliding : 0.0;
  state.counters["triangle_tests_per_edge"] =
      work.edges > 0 ? work.triangle_tests / work.edges : 0.0;
  state.counters["us_per_point"] = colliding > 0 ? total / colliding * 1e6 : 0.0;
  // what the paper times as resolving a colliding point: everything after
  // stage 1 has found it (surfaces, stages 2 to 4, closest features)
  double resolve = 0.0;
  for (int i = 2; i < kStages; ++i) resolve += stages[i];
  state.counters["us_resolve_per_point"] = colliding > 0 ? resolve / colliding * 1e6 : 0.0;
  const char* names[kStages] = {"ms_hash",      "ms_inside",    "ms_surfaces",
                                "ms_intersect", "ms_propagate", "ms_closest"};
  for (int i = 0; i < kStages; ++i) state.counters[names[i]] = stages[i] / iterations * 1e3;
}

// Solves the scene over and over: the same positions every time, or, in a
// moving scene, the next step's. (One configuration solved again and again
// lets the core's branch predictor learn a small scene's branches by heart:
// 120 paper spheres took 0.72 us a point so, against 0.96 moving, fastest
// of 6 runs; in a rollout, where the rest of the step runs between solves,
// the solver takes 2.4 to 2.9: see docs/performance.md.)
void Run(benchmark::State& state, Scene& scene) {
  PenetrationOptions options;
  options.method = state.range(1) == 0 ? DepthMethod::kConsistent : DepthMethod::kClosest;
  options.num_threads = static_cast<int>(state.range(2));
  PenetrationSolver solver(options);
  const bool moving = scene.moving();
  for (int step = 0; step < (moving ? kMovingSteps : 1); ++step) {  // warm: buffers grown
    if (moving) scene.ShowStep(step);
    solver.Solve(scene.objects);
  }
  double total = 0.0;
  Work work;
  double stages[kStages] = {};
  long solve = 0;
  for (auto _ : state) {
    if (moving) {  // (not timed)
      state.PauseTiming();
      scene.ShowStep(PingPong(solve++));
      state.ResumeTiming();
    }
    solver.Solve(scene.objects);
    const PenetrationTimings& t = solver.timings();
    total += t.total;
    const double s[kStages] = {t.hash, t.inside, t.surfaces, t.intersect, t.propagate, t.closest};
    for (int i = 0; i < kStages; ++i) stages[i] += s[i];
    const PenetrationStats& stats = solver.stats();
    work.colliding += stats.colliding;
    work.edges += stats.intersection_edges;
    work.tet_tests += static_cast<double>(stats.tet_tests);
    work.triangle_tests += static_cast<double>(stats.triangle_tests);
    benchmark::DoNotOptimize(solver.results().data());
  }
  Report(state, total, stages, work);
}

// The scenes the collision issue names, each twice: as built (BM_TwoCubes,
// ...), solved again and again, and moving (BM_TwoCubesMoving, ...), every
// object at up to kMovingSpeed, each solve the next time step.
void Finish(benchmark::State& state, Scene& scene, bool moving) {
  if (moving) scene.MakeMoving(kMovingSpeed);
  Run(state, scene);
}

void TwoCubes(benchmark::State& state, bool moving) {
  Scene scene;
  AddCubePairs(scene, static_cast<double>(state.range(0)) / 100.0, 1);
  Finish(state, scene, moving);
}
void TwoCubesArgs(benchmark::internal::Benchmark* b) {
  b->ArgsProduct({{10, 30, 50, 70}, {0, 1}, {1, 2}})
      ->ArgNames({"overlap%", "closest", "threads"})
      ->Unit(benchmark::kMicrosecond)
      ->UseRealTime();
}
void BM_TwoCubes(benchmark::State& state) {
  TwoCubes(state, false);
}
void BM_TwoCubesMoving(benchmark::State& state) {
  TwoCubes(state, true);
}
BENCHMARK(BM_TwoCubes)->Apply(TwoCubesArgs);
BENCHMARK(BM_TwoCubesMoving)->Apply(TwoCubesArgs);

void CubePairsScaling(benchmark::State& state, bool moving) {
  Scene scene;
  AddCubePairs(scene, 0.3, static_cast<int>(state.range(0)));
  Finish(state, scene, moving);
}
void CubePairsScalingArgs(benchmark::internal::Benchmark* b) {
  b->ArgsProduct({{1, 2, 5, 10}, {0}, {1}})
      ->ArgNames({"copies", "closest", "threads"})
      ->Unit(benchmark::kMicrosecond)
      ->UseRealTime();
}
void BM_CubePairsScaling(benchmark::State& state) {
  CubePairsScaling(state, false);
}
void BM_CubePairsScalingMoving(benchmark::State& state) {
  CubePairsScaling(state, true);
}
BENCHMARK(BM_CubePairsScaling)->Apply(CubePairsScalingArgs);
BENCHMARK(BM_CubePairsScalingMoving)->Apply(CubePairsScalingArgs);

// paper spheres (radius 2 cm, 20 tetrahedra) in a lattice of 6 layers
// spaced 1.5 radii with a seeded jitter: every sphere overlaps its
// neighbours; 120 in 5 x 4 x 6 (the paper's scene), and piles up to 80
// times as large, about as wide as long (how the cost per point grows with
// a pile's size): 240 in 5 x 8, 480 in 10 x 8, 1200 in 20 x 10, 2400 in
// 20 x 20, 4800 in 40 x 20, 9600 in 40 x 40 (x 6 layers)
void PaperSpheres(benchmark::State& state, bool moving) {
  Scene scene;
  const TetMesh& sphere = scene.Mesh("sphere:size=0.02:res=0");
  const int count = static_cast<int>(state.range(0));
  const int rows = count <= 240 ? 5 : count <= 480 ? 10 : count <= 2400 ? 20 : 40;
  const int columns = count / (6 * rows);
  std::mt19937 rng(2004);
  std::uniform_real_distribution<double> jitter(-0.003, 0.003);
  for (int i = 0; i < rows; ++i) {
    for (int j = 0; j < columns; ++j) {
      for (int k = 0; k < 6; ++k) {
        scene.Add(
            sphere,
            Eigen::Vector3d(0.03 * i + jitter(rng), 0.03 * j + jitter(rng), 0.03 * k + jitter(rng)),
            jitter(rng) * 300);
      }
    }
  }
  Finish(state, scene, moving);
}
void PaperSpheresArgs(benchmark::internal::Benchmark* b) {
  b->ArgsProduct({{120, 1200}, {0, 1}, {1, 2}})
      ->ArgsProduct({{240, 480, 2400, 4800, 9600}, {0}, {1}})
      ->ArgNames({"spheres", "closest", "threads"})
      ->Unit(benchmark::kMicrosecond)
      ->UseRealTime();
}
void BM_PaperSpheres(benchmark::State& state) {
  PaperSpheres(state, false);
}
void BM_PaperSpheresMoving(benchmark::State& state) {
  PaperSpheres(state, true);
}
BENCHMARK(BM_PaperSpheres)->Apply(PaperSpheresArgs);
BENCHMARK(BM_PaperSpheresMoving)->Apply(PaperSpheresArgs);

// about 100k tetrahedra: two blocks of 20 x 20 x 21 cells (50,400 tets each)
// overlapping by 20% of their width
void LargeScene(benchmark::State& state, bool moving) {
  Scene scene;
  const TetMesh& block = scene.Mesh("box:size=0.1,0.1,0.105:res=20,20,21");
  scene.Add(block, Eigen::Vector3d::Zero());
  scene.Add(block, Eigen::Vector3d(0.16, 0.013, -0.011), 0.05);
  Finish(state, scene, moving);
}
void LargeSceneArgs(benchmark::internal::Benchmark* b) {
  b->ArgsProduct({{100}, {0, 1}, {1, 2}})
      ->ArgNames({"ktets", "closest", "threads"})
      ->Unit(benchmark::kMillisecond)
      ->UseRealTime();
}
void BM_LargeScene(benchmark::State& state) {
  LargeScene(state, false);
}
void BM_LargeSceneMoving(benchmark::State& state) {
  LargeScene(state, true);
}
BENCHMARK(BM_LargeScene)->Apply(LargeSceneArgs);
BENCHMARK(BM_LargeSceneMoving)->Apply(LargeSceneArgs);

// a coarse box (one cell, 1 m: a rigid proxy meshed at resolution 1) with a
// corner in a finely meshed ball (radius 2 cm, subdivision `level`): the
// box's edges from that corner are hundreds of cells long (stage 2 then
// tests the ball's triangle hash whole; cell by cell, one solve took 0.5 s)
void BM_CoarseCorner(benchmark::State& state) {
  Scene scene;
  scene.Add(scene.Mesh("box:size=0.5,0.5,0.5:res=1"), Eigen::Vector3d::Zero());
  const std::string ball = "sphere:size=0.02:res=" + std::to_string(state.range(0));
  scene.Add(scene.Mesh(ball), Eigen::Vector3d(0.5, 0.5, 0.5));
  Run(state, scene);
}
BENCHMARK(BM_CoarseCorner)
    ->ArgsProduct({{4}, {0, 1}, {1, 2}})
    ->ArgNames({"level", "closest", "threads"})
    ->Unit(benchmark::kMicrosecond)
    ->UseRealTime();

// a ball (radius 3 cm, 1280 tetrahedra) enclosed in a block of 48,000: no
// border point, every point of the ball gets the closest-feature fallback
// (whose triangle table first held none of the block's triangles: 0.42 s
// a solve before it was sized again for them all)
void BM_EnclosedBall(benchmark::State& state) {
  Scene scene;
  scene.Add(scene.Mesh("box:size=0.1:res=20"), Eigen::Vector3d::Zero());
  scene.Add(scene.Mesh("sphere:size=0.03:res=2"), Eigen::Vector3d::Zero());
  Run(state, scene);
}
BENCHMARK(BM_EnclosedBall)
    ->ArgsProduct({{1280}, {0, 1}, {1, 2}})
    ->ArgNames({"tets", "closest", "threads"})
    ->Unit(benchmark::kMicrosecond)
    ->UseRealTime();

// 100 fine cubes (6 cm, 10,368 tetrahedra each) in a 10 x 10 grid, pressed
// 5 mm into a coarse rigid slab (1 m): on a slab of 20 x 20 x 1 cells, the
// slab's 2400 triangles are all too large to hash at the cubes' 5 mm cells
// (stage 2 finds them through a box tree); on one of 10 x 10 x 2 cells,
// the 288 tetrahedra that reach the cubes each cover more than 512 of the
// cubes' cells (stage 1 searches them through a coarser grid of the
// cubes' vertices)
void SlabUnderCubes(benchmark::State& state, const std::string& slab) {
  Scene scene;
  scene.Add(scene.Mesh(slab), Eigen::Vector3d::Zero());
  scene.objects.back().rigid = true;
  const TetMesh& cube = scene.Mesh("box:size=0.03:res=12");
  const int count = static_cast<int>(state.range(0));
  for (int k = 0; k < count; ++k) {
    const int row = k / 10, column = k % 10;  // (ten to a row)
    scene.Add(cube, Eigen::Vector3d(-0.45 + 0.1 * column, -0.45 + 0.1 * row, 0.075));
  }
  Run(state, scene);
}
void BM_CoarseSlab(benchmark::State& state) {
  SlabUnderCubes(state, "box:size=0.5,0.5,0.05:res=20,20,1");
}
void BM_MediumSlab(benchmark::State& state) {
  SlabUnderCubes(state, "box:size=0.5,0.5,0.05:res=10,10,2");
}
BENCHMARK(BM_CoarseSlab)
    ->ArgsProduct({{100}, {0, 1}, {1, 2}})
    ->ArgNames({"cubes", "closest", "threads"})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(BM_MediumSlab)
    ->ArgsProduct({{100}, {0, 1}, {1, 2}})
    ->ArgNames({"cubes", "closest", "threads"})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

// one small ball (2 cm, 320 tetrahedra) pressed 5 mm into a rigid slab (2 m
// x 2 m x 10 cm) of cells x cells x 2 cells, 6 tets each (25: 7,500 tets; 200:
// 480,000): the contact stays the same size while the slab grows, so this
// is what a large body costs a solve beyond its contacts (not fixed: its
// vertices, tetrahedra and faces are each passed over once a solve)
enum class Slab { kStill, kFixed, kTurning, kFramed };
void BallOnSlab(benchmark::State& state, Slab slab) {
  Scene scene;
  const int cells = static_cast<int>(state.range(0));
  scene.Add(scene.Mesh("box:size=1,1,0.05:res=" + std::to_string(cells) + "," +
                       std::to_string(cells) + ",2"),
            Eigen::Vector3d::Zero());
  scene.objects.back().rigid = true;
  scene.objects.back().fixed = slab == Slab::kFixed;
  scene.Add(scene.Mesh("sphere:size=0.02:res=2"), Eigen::Vector3d(0.0, 0.0, 0.065));
  if (slab == Slab::kTurning || slab == Slab::kFramed) {
    scene.MakeMoving(kMovingSpeed);
    scene.spin[0] = 1.0;
    if (slab == Slab::kFramed) scene.objects[0].frame = &scene.frames[0];
  }
  Run(state, scene);
}
void BallOnSlabArgs(benchmark::internal::Benchmark* b) {
  b->ArgsProduct({{25, 50, 100, 200}, {0, 1}, {1}})
      ->ArgNames({"cells", "closest", "threads"})
      ->Unit(benchmark::kMicrosecond)
      ->UseRealTime();
}
void BM_BallOnSlab(benchmark::State& state) {
  BallOnSlab(state, Slab::kStill);
}
BENCHMARK(BM_BallOnSlab)->Apply(BallOnSlabArgs);
// The same with the slab fixed (CollisionObject::fixed, as the bridge
// marks a proxy of a body welded to the world): the solver keeps the
// slab's box and a tree over its chunks, and passes over only the chunks
// near the ball.
void BM_BallOnFixedSlab(benchmark::State& state) {
  BallOnSlab(state, Slab::kFixed);
}
BENCHMARK(BM_BallOnFixedSlab)->Apply(BallOnSlabArgs);
// The slab turning (1 rad/s about z) and moving, as the ball does (each
// solve the next step): its positions given alone, and with the slab's
// frame and the box of its positions (CollisionObject::frame, with
// RigidFrame::bounds, as the bridge gives a moving body's proxy), so that
// the solver keeps a tree over its chunks in its body frame and passes
// over none of its positions beyond those near the ball.
void BM_BallOnTurningSlab(benchmark::State& state) {
  BallOnSlab(state, Slab::kTurning);
}
BENCHMARK(BM_BallOnTurningSlab)->Apply(BallOnSlabArgs);
void BM_BallOnFramedSlab(benchmark::State& state) {
  BallOnSlab(state, Slab::kFramed);
}
BENCHMARK(BM_BallOnFramedSlab)->Apply(BallOnSlabArgs);

// The broad phase alone, on the boxes of a pile laid out as the paper
// spheres' (4 cm boxes 3 cm apart with a seeded jitter, side x side x 6
// layers: 600 to 153,600 boxes): its cost a box as the pile grows, the
// partners a box has, and the strips it was cut into (one below 512 boxes).
void BM_BroadPhasePile(benchmark::State& state) {
  const int side = static_cast<int>(state.range(0));
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> jitter(-0.003, 0.003);
  std::vector<BroadPhaseBox> boxes;
  for (int i = 0; i < side; ++i) {
    for (int j = 0; j < side; ++j) {
      for (int k = 0; k < 6; ++k) {
        const Eigen::Vector3d centre(0.03 * i + jitter(rng), 0.03 * j + jitter(rng),
                                     0.03 * k + jitter(rng));
        BroadPhaseBox& box = boxes.emplace_back();
        box.lo = centre - Eigen::Vector3d::Constant(0.02);
        box.hi = centre + Eigen::Vector3d::Constant(0.02);
      }
    }
  }
  BroadPhase broad_phase;
  broad_phase.Find(boxes);  // (warm: buffers grown)
  for (auto _ : state) {
    broad_phase.Find(boxes);
    benchmark::DoNotOptimize(broad_phase.partner(0));
  }
  long partners = 0;
  for (int o = 0; o < static_cast<int>(boxes.size()); ++o) partners += broad_phase.num_partners(o);
  state.counters["boxes"] = static_cast<double>(boxes.size());
  state.counters["partners"] = static_cast<double>(partners) / static_cast<double>(boxes.size());
  state.counters["strips"] = broad_phase.num_strips();
  state.counters["s_per_box"] = benchmark::Counter(
      static_cast<double>(boxes.size()),
      benchmark::Counter::kIsIterationInvariantRate | benchmark::Counter::kInvert);
}
BENCHMARK(BM_BroadPhasePile)
    ->ArgName("side")
    ->Arg(10)
    ->Arg(20)
    ->Arg(40)
    ->Arg(80)
    ->Arg(160)
    ->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace tetcosim

BENCHMARK_MAIN();
