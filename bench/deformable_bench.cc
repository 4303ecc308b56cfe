// Time per step of the deformable module alone (no collision): a free box
// under gravity at resolutions of about 2k, 8k and 50k tetrahedra
// (n x n x n cells, 6 tetrahedra each), E = 5e4 and 1e7 Pa, dt = 1 and 10
// ms, with CG iterations per step. Arguments: (cells per axis, E, dt in
// 0.1 ms, solver 0 CG / 1 LDL^T, threads, CG product 0 auto / 1 assembled /
// 2 element-wise).

#include <benchmark/benchmark.h>

#include "deformable/coupled_step.h"
#include "deformable/deformable_body.h"
#include "mesh/generators.h"

namespace tetcosim {
namespace {

void BM_DeformableStep(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  const double young = static_cast<double>(state.range(1));
  const double dt = static_cast<double>(state.range(2)) * 1e-4;
  auto mesh =
      std::make_shared<TetMesh>(TetMesh::Build(MakeBox({0.245, 0.245, 0.245}, {n, n, n}, 6)));
  auto model = FemModel::Build(mesh, Material{young, 0.3, 1000, 0.0, 0.0});
  DeformableBody body(model, "block");
  // pin the bottom layer so that the block deforms under gravity instead of
  // falling freely (a free fall would be solved in one iteration)
  for (int v = 0; v < body.num_vertices(); ++v) {
    if (body.positions()(v, 2) < -0.2449) body.Pin(v);
  }
  StepSettings settings;
  settings.dt = dt;
  settings.solver =
      state.range(3) == 0 ? LinearSolver::kConjugateGradient : LinearSolver::kCholesky;
  settings.num_threads = static_cast<int>(state.range(4));
  if (state.range(5) == 1) settings.system_product = SystemProduct::kAssembled;
  if (state.range(5) == 2) settings.system_product = SystemProduct::kElementWise;
  for (int s = 0; s < 5; ++s) body.Step(settings);  // warm up: the block starts to sag
  long iterations = 0;
  for (auto _ : state) {
    StepReport report = body.Step(settings);
    iterations += report.iterations;
    if (report.status != StepStatus::kOk) state.SkipWithError("diverged");
  }
  state.counters["tets"] = model->num_tets();
  state.counters["cg_iterations"] =
      static_cast<double>(iterations) / static_cast<double>(state.iterations());
}
BENCHMARK(BM_DeformableStep)
    ->ArgsProduct({{7, 11, 20}, {50000, 10000000}, {10, 100}, {0}, {1, 2}, {0}})
    ->ArgNames({"cells", "E", "dt_0.1ms", "ldlt", "threads", "product"})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(BM_DeformableStep)
    ->ArgsProduct({{7, 11}, {50000, 10000000}, {10, 100}, {1}, {1}, {0}})
    ->ArgNames({"cells", "E", "dt_0.1ms", "ldlt", "threads", "product"})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

// the CG solve's two ways to apply the system matrix, forced (product 1:
// assembled once per step, 2: element by element), against kAuto above
BENCHMARK(BM_DeformableStep)
    ->ArgsProduct({{7, 20}, {50000, 10000000}, {10, 100}, {0}, {1, 2}, {1, 2}})
    ->ArgNames({"cells", "E", "dt_0.1ms", "ldlt", "threads", "product"})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

}  // namespace
}  // namespace tetcosim

BENCHMARK_MAIN();
