#include "deformable/deformable_body.h"

#include <algorithm>
#include <cmath>
#include <string>

#include "deformable/corotational.h"
#include "deformable/coupled_step.h"
#include "mesh/error.h"
#include "mesh/parallel_for.h"

namespace tetcosim {

namespace {

// StepSettings::num_threads and ::system_product (kAuto): measured limits
constexpr int kMinTetsForThreads = 16384;
constexpr int kMaxTetsToAssemble = 16384;

// Calls visit(k, batch) for every batch of up to four tetrahedra
// (FemModel::ElementBatch): in mesh order on one thread (memory locality);
// with more, one colour at a time, in parallel within a colour. No two
// elements of a colour share a vertex, so a visit may scatter into its
// vertices without races, and the summation order is fixed for any thread
// count above one. The last colour may hold tets that share vertices: it
// runs serially. k indexes model.serial_batches() on one thread, else
// model.colored_batches().
template <typename Visit>
void ForEachBatch(const FemModel& model, int num_threads, const Visit& visit) {
  if (num_threads <= 1) {
    const std::vector<ElementBatch>& batches = model.serial_batches();
    for (int k = 0; k < static_cast<int>(batches.size()); ++k) visit(k, batches[k]);
    return;
  }
  const std::vector<ElementBatch>& batches = model.colored_batches();
  const std::vector<int>& offsets = model.color_batch_offsets();
  for (int color = 0; color + 1 < static_cast<int>(offsets.size()); ++color) {
    ParallelFor(color < 63 ? num_threads : 1, offsets[color], offsets[color + 1],
                [&](int k) { visit(k, batches[k]); });
  }
}

// lane by lane: D[r][j] = (x_{j+1} - x_0)[r] for the tets of a batch (zero
// in unused lanes)
inline Lanes3x3 GatherEdges(const double* x, const Tets& tets, const ElementBatch& batch) {
  static constexpr double kZero[3] = {0.0, 0.0, 0.0};
  const double* p[4][4];  // [lane][vertex]
  for (int lane = 0; lane < 4; ++lane) {
    const int t = batch.tets[lane];
    for (int i = 0; i < 4; ++i) p[lane][i] = t < 0 ? kZero : x + 3 * tets(t, i);
  }
  Lanes3x3 D;
  for (int j = 0; j < 3; ++j) {
    for (int r = 0; r < 3; ++r) {
      D[r][j] = Lanes(p[0][j + 1][r], p[1][j + 1][r], p[2][j + 1][r], p[3][j + 1][r]) -
                Lanes(p[0][0][r], p[1][0][r], p[2][0][r], p[3][0][r]);
    }
  }
  return D;
}

// the transpose of GatherEdges, added to y lane by lane in order:
// y_{j+1} += f[j], y_0 -= f[0] + f[1] + f[2] (f[j][r], unused lanes skipped)
inline void ScatterEdges(const Lanes3x3& f, const Tets& tets, const ElementBatch& batch,
                         double* y) {
  for (int lane = 0; lane < 4; ++lane) {
    const int t = batch.tets[lane];
    if (t < 0) continue;
    double* y0 = y + 3 * tets(t, 0);
    for (int j = 0; j < 3; ++j) {
      double* yj = y + 3 * tets(t, j + 1);
      for (int r = 0; r < 3; ++r) yj[r] += f[j][r][lane];
    }
    for (int r = 0; r < 3; ++r) y0[r] -= f[0][r][lane] + f[1][r][lane] + f[2][r][lane];
  }
}

}  // namespace

DeformableBody::DeformableBody(std::shared_ptr<const FemModel> model, std::string name)
    : model_(std::move(model)), name_(std::move(name)) {
  const int n = model_->num_vertices();
  x_ = model_->mesh().positions();
  v_.setZero(n, 3);
  applied_.setZero(n, 3);
  rotations_.assign(model_->num_tets(), Eigen::Quaterniond::Identity());
  // the system matrix on the model's pattern (values refilled every step)
  const std::vector<int>& row_start = model_->row_start();
  const std::vector<int>& columns = model_->columns();
  A_.resize(3 * n, 3 * n);
  A_.reserve(static_cast<Eigen::Index>(columns.size()));
  std::vector<Eigen::Triplet<double>> triplets;
  triplets.reserve(columns.size());
  for (int row = 0; row < 3 * n; ++row) {
    for (int k = row_start[row]; k < row_start[row + 1]; ++k) {
      triplets.emplace_back(row, columns[k], 1.0);
    }
  }
  A_.setFromTriplets(triplets.begin(), triplets.end());
  A_.makeCompressed();
  b_.setZero(3 * n);
  solution_.setZero(3 * n);
}

DeformableBody::~DeformableBody() = default;

void DeformableBody::Reset(const Eigen::Isometry3d& X_WB, const Eigen::Vector3d& v) {
  const Positions& rest = model_->mesh().positions();
  for (Eigen::Index i = 0; i < rest.rows(); ++i) {
    x_.row(i) = (X_WB * rest.row(i).transpose()).transpose();
    v_.row(i) = v.transpose();
  }
  Eigen::Quaterniond q(X_WB.rotation());
  rotations_.assign(model_->num_tets(), q);
}

void DeformableBody::Pin(int vertex) {
  if (vertex < 0 || vertex >= num_vertices()) {
    throw Error(name_ + ": pinned vertex " + std::to_string(vertex) + " is out of range");
  }
  auto it = std::lower_bound(pinned_.begin(), pinned_.end(), vertex);
  size_t index = static_cast<size_t>(it - pinned_.begin());
  if (it != pinned_.end() && *it == vertex) {
    pin_frame_[index] = -1;
    pin_target_[index] = x_.row(vertex).transpose();
    return;
  }
  pinned_.insert(it, vertex);
  pin_frame_.insert(pin_frame_.begin() + static_cast<long>(index), -1);
  pin_target_.insert(pin_target_.begin() + static_cast<long>(index), x_.row(vertex).transpose());
  pin_forces_.assign(pinned_.size(), Eigen::Vector3d::Zero());
}

int DeformableBody::PinToFrame(const std::vector<int>& vertices, const Eigen::Isometry3d& X_WT) {
  const int frame = static_cast<int>(frames_.size());
  frames_.push_back(X_WT);
  for (int v : vertices) {
    Pin(v);
    auto index =
        static_cast<size_t>(std::lower_bound(pinned_.begin(), pinned_.end(), v) - pinned_.begin());
    pin_frame_[index] = frame;
    pin_target_[index] = X_WT.inverse() * x_.row(v).transpose();
  }
  return frame;
}

// A = (1 + dt alpha) M + (dt beta + dt^2) K
// b = M v + dt (f_elastic + M g + f_applied)
// (contact terms are added by coupled_step.h)
void DeformableBody::Assemble(const StepSettings& settings, bool matrix) {
  const FemModel& model = *model_;
  const TetMesh& mesh = model.mesh();
  const double dt = settings.dt;
  const double mu = model.mu();
  const double lambda = model.lambda();
  const double stiffness_scale = dt * model.material().damping_stiffness + dt * dt;
  const double mass_scale = 1.0 + dt * model.material().damping_mass;
  double* values = A_.valuePtr();
  const std::vector<int>& row_start = model.row_start();
  if (matrix) std::fill(values, values + A_.nonZeros(), 0.0);
  b_.setZero();
  assembled_ = matrix;
  mass_scale_ = mass_scale;
  num_threads_ = RunsOnSeveralThreads(model, settings) ? settings.num_threads : 1;
  const std::vector<ElementBatch>& batches =
      num_threads_ > 1 ? model.colored_batches() : model.serial_batches();
  batch_systems_.resize(batches.size());
  diagonal_blocks_.assign(model.num_vertices(), Eigen::Matrix3d::Zero());

  // element loop, four elements at a time (ForEachBatch: deterministic for
  // any thread count; lanes scatter in order)
  ForEachBatch(model, num_threads_, [&](int k, const ElementBatch& batch) {
    // gather: edges x_j - x_0, rest gradients b_1..b_3 (b_0 = -(b_1 + b_2 +
    // b_3)), volumes, warm starts
    const Lanes3x3 D = GatherEdges(x_.data(), mesh.tets(), batch);
    Lanes3x3 grad;  // grad[j][c] = (b_{j+1})_c
    for (auto& row : grad) row.fill(Lanes::Zero());
    Lanes volume = Lanes::Zero();
    LaneQuaternion q = {Lanes::Ones(), Lanes::Zero(), Lanes::Zero(), Lanes::Zero()};
    for (int lane = 0; lane < 4; ++lane) {
      const int t = batch.tets[lane];
      if (t < 0) continue;
      const Eigen::Matrix<double, 4, 3>& b = model.gradients()[t];
      for (int j = 0; j < 3; ++j) {
        for (int c = 0; c < 3; ++c) grad[j][c][lane] = b(j + 1, c);
      }
      volume[lane] = mesh.rest_volumes()[t];
      const Eigen::Quaterniond& rotation = rotations_[t];
      q[0][lane] = rotation.w();
      q[1][lane] = rotation.x();
      q[2][lane] = rotation.y();
      q[3][lane] = rotation.z();
    }
    // F = sum_j (x_j - x_0) b_j^T, and its rotation
    Lanes3x3 F;
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) {
        F[r][c] = D[r][0] * grad[0][c] + D[r][1] * grad[1][c] + D[r][2] * grad[2][c];
      }
    }
    const Lanes3x3 R =
        ExtractRotations(F, q, settings.rotation_iterations, settings.rotation_tolerance);
    // impulse of the elastic forces, -dt V P b_i, with
    // P = 2 mu (F - R) + lambda tr(R^T F - I) R
    Lanes trace = -3.0 * Lanes::Ones();
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) trace += R[r][c] * F[r][c];
    }
    Lanes3x3 P;  // -dt V P
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) {
        P[r][c] = (-dt * volume) * (2.0 * mu * (F[r][c] - R[r][c]) + lambda * trace * R[r][c]);
      }
    }
    // c_j = R b_j (C[r][j]) and the impulses f_j (f[j][r]), j = 1..3
    Lanes3x3 C, f;
    for (int r = 0; r < 3; ++r) {
      for (int j = 0; j < 3; ++j) {
        C[r][j] = R[r][0] * grad[j][0] + R[r][1] * grad[j][1] + R[r][2] * grad[j][2];
        f[j][r] = P[r][0] * grad[j][0] + P[r][1] * grad[j][1] + P[r][2] * grad[j][2];
      }
    }
    BatchSystem& system = batch_systems_[k];
    system.c = C;
    const Lanes s = stiffness_scale * volume;
    system.mu_scale = s * mu;
    system.lambda_scale = s * lambda;
    // K_ii = s V [(lambda + mu) c_i c_i^T + mu |c_i|^2 I] for the
    // preconditioner, upper triangle (b_i . b_i = c_i . c_i)
    std::array<std::array<Lanes, 6>, 4> diagonal;
    for (int i = 0; i < 4; ++i) {
      std::array<Lanes, 3> ci;
      for (int r = 0; r < 3; ++r) {
        ci[r] = i == 0 ? Lanes(-(C[r][0] + C[r][1] + C[r][2])) : C[r][i - 1];
      }
      const Lanes a = s * (lambda + mu);
      const Lanes d = s * mu * (ci[0] * ci[0] + ci[1] * ci[1] + ci[2] * ci[2]);
      diagonal[i] = {a * ci[0] * ci[0] + d, a * ci[0] * ci[1], a * ci[0] * ci[2],
                     a * ci[1] * ci[1] + d, a * ci[1] * ci[2], a * ci[2] * ci[2] + d};
    }
    // scatter, lane by lane in order
    ScatterEdges(f, mesh.tets(), batch, b_.data());
    for (int lane = 0; lane < 4; ++lane) {
      const int t = batch.tets[lane];
      if (t < 0) continue;
      const auto tet = mesh.tets().row(t);
      rotations_[t] = Eigen::Quaterniond(q[0][lane], q[1][lane], q[2][lane], q[3][lane]);
      for (int i = 0; i < 4; ++i) {
        Eigen::Matrix3d& block = diagonal_blocks_[tet[i]];
        const std::array<Lanes, 6>& u = diagonal[i];
        block(0, 0) += u[0][lane];
        block(0, 1) += u[1][lane];
        block(0, 2) += u[2][lane];
        block(1, 0) += u[1][lane];
        block(1, 1) += u[3][lane];
        block(1, 2) += u[4][lane];
        block(2, 0) += u[2][lane];
        block(2, 1) += u[4][lane];
        block(2, 2) += u[5][lane];
      }
      if (matrix) {
        Eigen::Matrix<double, 4, 3> c;  // rows c_i
        for (int j = 0; j < 3; ++j) {
          for (int r = 0; r < 3; ++r) c(j + 1, r) = C[r][j][lane];
        }
        c.row(0) = -(c.row(1) + c.row(2) + c.row(3));
        AddElementMatrix(t, c, s[lane], values);
      }
    }
  });
  const Eigen::VectorXd& masses = model.masses();
  double outside = 0.0;  // (squared)
  for (int v = 0; v < model.num_vertices(); ++v) {
    const double m = masses[v];
    diagonal_blocks_[v].diagonal().array() += mass_scale * m;
    if (matrix) {
      for (int r = 0; r < 3; ++r) {
        values[row_start[3 * v + r] + model.diagonal_slot()[v] + r] += mass_scale * m;
      }
    }
    const Eigen::Vector3d impulse = dt * (m * settings.gravity + applied_.row(v).transpose());
    b_.segment<3>(3 * v) += m * v_.row(v).transpose() + impulse;
    outside += impulse.squaredNorm();
  }
  outside_impulse_ = std::sqrt(outside);
}

// values += s K_e at element t's slots, with the rows c_i = R b_i (4 x 3):
// K_ij = lambda c_i c_j^T + mu c_j c_i^T + mu (b_i . b_j) I, K_ji = K_ij^T
void DeformableBody::AddElementMatrix(int t, const Eigen::Matrix<double, 4, 3>& c, double s,
                                      double* values) const {
  const FemModel& model = *model_;
  const auto tet = model.mesh().tets().row(t);
  const Eigen::Matrix<double, 4, 3>& grad = model.gradients()[t];
  const std::array<int, 16>& slots = model.element_slots()[t];
  const std::vector<int>& row_start = model.row_start();
  const double s_mu = s * model.mu();
  const double s_lambda = s * model.lambda();
  // (scalars, not Eigen's outer products: the same arithmetic, but a
  // sanitizer build at -O1, which inlines little, took half of a stiff
  // body's rollout here)
  for (int a = 0; a < 4; ++a) {
    const int row_a = row_start[3 * tet[a]];
    const int length_a = row_start[3 * tet[a] + 1] - row_a;
    const double ca[3] = {c(a, 0), c(a, 1), c(a, 2)};
    for (int bb = a; bb < 4; ++bb) {
      const double cb[3] = {c(bb, 0), c(bb, 1), c(bb, 2)};
      // (b_a . b_b summed in the order of Eigen's dot product of three)
      const double diagonal =
          s_mu * (grad(a, 0) * grad(bb, 0) + (grad(a, 1) * grad(bb, 1) + grad(a, 2) * grad(bb, 2)));
      double block[3][3];
      for (int r = 0; r < 3; ++r) {
        for (int q = 0; q < 3; ++q) {
          block[r][q] = s_lambda * ca[r] * cb[q] + s_mu * cb[r] * ca[q];
        }
        block[r][r] += diagonal;
      }
      double* entry = values + row_a + slots[4 * a + bb];
      for (int r = 0; r < 3; ++r, entry += length_a) {
        entry[0] += block[r][0];
        entry[1] += block[r][1];
        entry[2] += block[r][2];
      }
      if (bb == a) continue;
      const int row_b = row_start[3 * tet[bb]];
      const int length_b = row_start[3 * tet[bb] + 1] - row_b;
      double* mirror = values + row_b + slots[4 * bb + a];
      for (int r = 0; r < 3; ++r, mirror += length_b) {
        mirror[0] += block[0][r];
        mirror[1] += block[1][r];
        mirror[2] += block[2][r];
      }
    }
  }
}

// y = (1 + dt alpha) M x + sum_e s V K_e x_e with, for linear tets and
// c_i = R b_i, K_e x_e at vertex i = (lambda tr(G) I + mu (G + G^T)) c_i,
// G = sum_j x_j c_j^T: the co-rotated linear stress of the "strain" G.
// Since c_0 = -(c_1 + c_2 + c_3): G = sum_{j>0} (x_j - x_0) c_j^T, and
// vertex 0 receives minus the sum of the others
void DeformableBody::MultiplyElementWise(const double* x, double* y) const {
  const FemModel& model = *model_;
  const TetMesh& mesh = model.mesh();
  MultiplyMass(x, y);
  // element loop, four at a time, ordered as in Assemble
  ForEachBatch(model, num_threads_, [&](int k, const ElementBatch& batch) {
    const BatchSystem& system = batch_systems_[k];
    const Lanes3x3& C = system.c;
    const Lanes3x3 D = GatherEdges(x, mesh.tets(), batch);
    Lanes3x3 G;  // sum_j D_j c_j^T
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) {
        G[r][c] = D[r][0] * C[c][0] + D[r][1] * C[c][1] + D[r][2] * C[c][2];
      }
    }
    const Lanes lambda_trace = system.lambda_scale * (G[0][0] + G[1][1] + G[2][2]);
    Lanes3x3 S;  // mu s V (G + G^T) + lambda s V tr(G) I
    for (int r = 0; r < 3; ++r) {
      for (int c = r; c < 3; ++c) {
        S[r][c] = system.mu_scale * (G[r][c] + G[c][r]);
        S[c][r] = S[r][c];
      }
      S[r][r] += lambda_trace;
    }
    Lanes3x3 f;  // f[j][r] = (S c_j)_r, vertex j + 1
    for (int j = 0; j < 3; ++j) {
      for (int r = 0; r < 3; ++r) {
        f[j][r] = S[r][0] * C[0][j] + S[r][1] * C[1][j] + S[r][2] * C[2][j];
      }
    }
    ScatterEdges(f, mesh.tets(), batch, y);
  });
}

void DeformableBody::MultiplyMass(const double* x, double* y) const {
  const Eigen::VectorXd& masses = model_->masses();
  for (int v = 0; v < model_->num_vertices(); ++v) {
    const double m = mass_scale_ * masses[v];
    y[3 * v] = m * x[3 * v];
    y[3 * v + 1] = m * x[3 * v + 1];
    y[3 * v + 2] = m * x[3 * v + 2];
  }
}

void DeformableBody::MultiplySystem(const double* x, double* y) const {
  if (!assembled_) {
    MultiplyElementWise(x, y);
    return;
  }
  const std::vector<int>& row_start = model_->row_start();
  const std::vector<int>& columns = model_->columns();
  const double* values = A_.valuePtr();
  const int num_vertices = model_->num_vertices();
  // rows are independent: the same result for any thread count
  ParallelFor(num_threads_, 0, num_vertices, [&](int v) {
    const int begin = row_start[3 * v];
    const int length = row_start[3 * v + 1] - begin;  // the same for the three rows
    const double* a0 = values + begin;
    const double* a1 = a0 + length;
    const double* a2 = a1 + length;
    const int* column = columns.data() + begin;
    double y0 = 0.0, y1 = 0.0, y2 = 0.0;
    for (int k = 0; k < length; k += 3) {
      const double* xu = x + column[k];  // 3u, 3u+1, 3u+2
      y0 += a0[k] * xu[0] + a0[k + 1] * xu[1] + a0[k + 2] * xu[2];
      y1 += a1[k] * xu[0] + a1[k + 1] * xu[1] + a1[k + 2] * xu[2];
      y2 += a2[k] * xu[0] + a2[k + 1] * xu[1] + a2[k + 2] * xu[2];
    }
    y[3 * v] = y0;
    y[3 * v + 1] = y1;
    y[3 * v + 2] = y2;
  });
}

// pinned DoFs: v+ = (target - x) / dt, eliminated from the system symmetrically
void DeformableBody::ApplyPins(const StepSettings& settings) {
  if (pinned_.empty()) return;
  const FemModel& model = *model_;
  const std::vector<int>& row_start = model.row_start();
  const std::vector<int>& columns = model.columns();
  double* values = A_.valuePtr();
  // keep the original rows for the pin forces
  pinned_rows_.clear();
  pinned_b_.resize(3 * static_cast<Eigen::Index>(pinned_.size()));
  for (size_t i = 0; i < pinned_.size(); ++i) {
    for (int r = 0; r < 3; ++r) {
      int row = 3 * pinned_[i] + r;
      pinned_rows_.insert(pinned_rows_.end(), values + row_start[row], values + row_start[row + 1]);
      pinned_b_[3 * static_cast<Eigen::Index>(i) + r] = b_[row];
    }
  }
  for (size_t i = 0; i < pinned_.size(); ++i) {
    const int p = pinned_[i];
    const Eigen::Vector3d target = PinTarget(i);
    Eigen::Vector3d velocity = (target - x_.row(p).transpose()) / settings.dt;
    // move column p to the right-hand side in every other row
    for (int k = row_start[3 * p]; k < row_start[3 * p + 1]; k += 3) {
      const int u = columns[k] / 3;
      if (u == p) continue;
      int slot = model.diagonal_slot()[u];  // find p among u's columns
      {
        const int* begin = columns.data() + row_start[3 * u];
        const int* end = columns.data() + row_start[3 * u + 1];
        slot = static_cast<int>(std::lower_bound(begin, end, 3 * p) - begin);
      }
      for (int r = 0; r < 3; ++r) {
        double* row = values + row_start[3 * u + r] + slot;
        for (int c = 0; c < 3; ++c) {
          b_[3 * u + r] -= row[c] * velocity[c];
          row[c] = 0.0;
        }
      }
    }
    for (int r = 0; r < 3; ++r) {
      int row = 3 * p + r;
      std::fill(values + row_start[row], values + row_start[row + 1], 0.0);
      values[row_start[row] + model.diagonal_slot()[p] + r] = 1.0;
      b_[row] = velocity[r];
    }
  }
}

// solves for the velocity change dv = v+ - v: A dv = b - A v, so that the
// solver's relative tolerance applies to the change, not to the momentum
void DeformableBody::Solve(StepReport& report) {
  Eigen::Map<const Eigen::VectorXd> v(v_.data(), v_.size());
  rhs_.noalias() = b_ - A_ * v;
  if (delta_v_.size() != rhs_.size()) delta_v_.setZero(rhs_.size());
  // sparse LDLT (the conjugate-gradient path goes through StepCoupled)
  Eigen::SparseMatrix<double> A = A_;  // column-major copy (A is symmetric)
  if (!ldlt_analyzed_) {
    ldlt_.analyzePattern(A);
    ldlt_analyzed_ = true;
  }
  ldlt_.factorize(A);
  delta_v_ = ldlt_.solve(rhs_);
  report.iterations = 0;
  double norm = rhs_.norm();
  report.residual = norm > 0.0 ? (A_ * delta_v_ - rhs_).norm() / norm : 0.0;
  solution_ = v + delta_v_;
}

void StepSettings::Validate() const {
  auto fail = [](const std::string& message) { throw Error("step settings: " + message); };
  if (!(dt > 0.0) || !std::isfinite(dt)) {
    fail("dt is " + std::to_string(dt) + " s; give a finite time step > 0");
  }
  if (!gravity.allFinite()) fail("gravity is not finite");
  if (!(cg_tolerance >= 0.0) || !std::isfinite(cg_tolerance) || !(rotation_tolerance >= 0.0) ||
      !std::isfinite(rotation_tolerance)) {
    fail("cg_tolerance and rotation_tolerance must be finite and >= 0");
  }
  if (cg_max_iterations < 1 || rotation_iterations < 1) {
    fail("cg_max_iterations and rotation_iterations must be at least 1");
  }
}

StepReport DeformableBody::Step(const StepSettings& settings) {
  StepReport report;
  if (settings.solver == LinearSolver::kConjugateGradient) {
    // the coupled step's solver with no contacts: block-Jacobi PCG on the
    // vertex-blocked product, pins as prescribed velocities
    DeformableBody* self = this;
    if (!step_workspace_) step_workspace_ = std::make_unique<CoupledStepWorkspace>();
    const CoupledStepReport coupled =
        StepCoupled(std::span<DeformableBody* const>(&self, 1), {}, ContactSettings{}, settings,
                    /*rigid=*/nullptr, step_workspace_.get());
    report.status = coupled.status;
    report.bad_vertex = coupled.bad_vertex;
    report.iterations = coupled.iterations;
    report.residual = coupled.residual;
    return report;
  }
  settings.Validate();  // (the path above: StepCoupled checks them)
  Eigen::setNbThreads(std::max(1, settings.num_threads));
  Assemble(settings, true);
  ApplyPins(settings);
  Solve(report);

  // commit only a finite state; a vertex with a non-finite momentum or
  // force, whose b makes the whole solution non-finite, is the one reported
  const int n = num_vertices();
  for (int v = 0; v < n; ++v) {
    if (!b_.segment<3>(3 * v).allFinite()) {
      report.status = StepStatus::kDiverged;
      report.bad_vertex = v;
      return report;
    }
  }
  Eigen::Map<const Positions> v_new(solution_.data(), n, 3);
  for (int v = 0; v < n; ++v) {
    if (!v_new.row(v).allFinite() || !(x_.row(v) + settings.dt * v_new.row(v)).allFinite()) {
      report.status = StepStatus::kDiverged;
      report.bad_vertex = v;
      break;
    }
  }
  if (report.status == StepStatus::kOk) {
    // pin forces: f_pin = (A_orig v+ - b_orig) / dt on the pinned rows
    const std::vector<int>& row_start = model_->row_start();
    const std::vector<int>& columns = model_->columns();
    size_t offset = 0;
    pin_forces_.assign(pinned_.size(), Eigen::Vector3d::Zero());
    for (size_t i = 0; i < pinned_.size(); ++i) {
      for (int r = 0; r < 3; ++r) {
        int row = 3 * pinned_[i] + r;
        double sum = 0.0;
        for (int k = row_start[row]; k < row_start[row + 1]; ++k) {
          sum += pinned_rows_[offset++] * solution_[columns[k]];
        }
        pin_forces_[i][r] = (sum - pinned_b_[3 * static_cast<Eigen::Index>(i) + r]) / settings.dt;
      }
    }
    v_ = v_new;
    x_ += settings.dt * v_;
  }
  return report;
}

void DeformableBody::Save(Memory* memory) const {
  memory->x = x_;
  memory->v = v_;
  memory->applied = applied_;
  memory->frames = frames_;
  memory->rotations = rotations_;
  memory->velocity_change = delta_v_;
  memory->last_iterations = last_iterations_;
  memory->pin_forces = pin_forces_;
}

void DeformableBody::Restore(const Memory& memory) {
  x_ = memory.x;
  v_ = memory.v;
  applied_ = memory.applied;
  frames_ = memory.frames;
  rotations_ = memory.rotations;
  delta_v_ = memory.velocity_change;
  last_iterations_ = memory.last_iterations;
  pin_forces_ = memory.pin_forces;
}

bool DeformableBody::RunsOnSeveralThreads(const FemModel& model, const StepSettings& settings) {
  return model.num_tets() >= kMinTetsForThreads && settings.num_threads > 1;
}

void DeformableBody::PrepareStep(const StepSettings& settings) {
  // kAuto: see StepSettings::system_product
  const bool threaded = RunsOnSeveralThreads(*model_, settings);
  const bool matrix = settings.system_product == SystemProduct::kAssembled ||
                      (settings.system_product == SystemProduct::kAuto && last_iterations_ >= 12 &&
                       (model_->num_tets() <= kMaxTetsToAssemble || threaded));
  Assemble(settings, matrix);
}

Eigen::Vector3d DeformableBody::PinTarget(size_t i) const {
  const int frame = pin_frame_[i];
  return frame >= 0 ? Eigen::Vector3d(frames_[frame] * pin_target_[i]) : pin_target_[i];
}

Eigen::Vector3d DeformableBody::PinVelocity(size_t i, double dt) const {
  return (PinTarget(i) - x_.row(pinned_[i]).transpose()) / dt;
}

StepReport DeformableBody::FinishStep(const Eigen::Ref<const Eigen::VectorXd>& v_new,
                                      const Eigen::Ref<const Eigen::VectorXd>& residual,
                                      const StepSettings& settings, int iterations) {
  StepReport report;
  last_iterations_ = iterations;
  const int n = num_vertices();
  Eigen::Map<const Positions> velocities(v_new.data(), n, 3);
  for (int v = 0; v < n; ++v) {
    // (a non-finite force leaves the solve's residual there non-finite, and
    // may leave v_new finite: the solve stopped at once)
    if (!velocities.row(v).allFinite() ||
        !(x_.row(v) + settings.dt * velocities.row(v)).allFinite() ||
        !residual.segment<3>(3 * v).allFinite()) {
      report.status = StepStatus::kDiverged;
      report.bad_vertex = v;
      break;
    }
  }
  if (report.status == StepStatus::kOk) {
    pin_forces_.assign(pinned_.size(), Eigen::Vector3d::Zero());
    for (size_t i = 0; i < pinned_.size(); ++i) {
      pin_forces_[i] = residual.segment<3>(3 * pinned_[i]) / settings.dt;
    }
    delta_v_ = v_new - Eigen::Map<const Eigen::VectorXd>(v_.data(), v_.size());  // warm start
    v_ = velocities;
    x_ += settings.dt * v_;
  }
  return report;
}

Positions DeformableBody::ElasticForces() {
  const FemModel& model = *model_;
  Positions forces = Positions::Zero(num_vertices(), 3);
  for (int t = 0; t < model.num_tets(); ++t) {
    const auto tet = model.mesh().tets().row(t);
    const Eigen::Matrix3d F = ElementDeformation(t);
    // converged polar rotation: forces exactly the energy gradient
    const Eigen::Matrix3d R = ExtractRotation(F, rotations_[t], 100, 1e-15);
    const Eigen::Matrix3d VP =
        model.mesh().rest_volumes()[t] * CorotatedStress(F, R, model.mu(), model.lambda());
    for (int i = 0; i < 4; ++i) {
      forces.row(tet[i]) -= (VP * model.gradients()[t].row(i).transpose()).transpose();
    }
  }
  return forces;
}

double DeformableBody::KineticEnergy() const {
  return 0.5 * (model_->masses().array() * v_.rowwise().squaredNorm().array()).sum();
}

double DeformableBody::ElasticEnergy() const {
  const FemModel& model = *model_;
  double energy = 0.0;
  for (int t = 0; t < model.num_tets(); ++t) {
    const Eigen::Matrix3d F = ElementDeformation(t);
    Eigen::Quaterniond q = rotations_[t];
    Eigen::Matrix3d R = ExtractRotation(F, q);
    energy +=
        model.mesh().rest_volumes()[t] * CorotatedEnergyDensity(F, R, model.mu(), model.lambda());
  }
  return energy;
}

Eigen::Matrix3d DeformableBody::ElementDeformation(int t) const {
  const FemModel& model = *model_;
  Eigen::Vector3d x[4];
  for (int i = 0; i < 4; ++i) x[i] = x_.row(model.mesh().tets()(t, i)).transpose();
  return DeformationGradient(model.gradients()[t], x);
}

Eigen::Quaterniond DeformableBody::ElementRotation(int t) const {
  Eigen::Quaterniond q = rotations_[t];
  ExtractRotation(ElementDeformation(t), q);
  return q;
}

double DeformableBody::GravitationalEnergy(const Eigen::Vector3d& gravity) const {
  return -(model_->masses().transpose() * (x_ * gravity))(0);
}

Eigen::Vector3d DeformableBody::LinearMomentum() const {
  return (v_.array().colwise() * model_->masses().array()).colwise().sum().transpose();
}

Eigen::Vector3d DeformableBody::AngularMomentum() const {
  Eigen::Vector3d L = Eigen::Vector3d::Zero();
  for (int v = 0; v < num_vertices(); ++v) {
    L += model_->masses()[v] * x_.row(v).transpose().cross(v_.row(v).transpose());
  }
  return L;
}

Eigen::Vector3d DeformableBody::CenterOfMass() const {
  return (x_.array().colwise() * model_->masses().array()).colwise().sum().transpose() /
         model_->total_mass();
}

Eigen::Vector3d DeformableBody::CenterOfMassVelocity() const {
  return LinearMomentum() / model_->total_mass();
}

}  // namespace tetcosim
