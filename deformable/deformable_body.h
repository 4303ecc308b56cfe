#pragma once

// A deformable body: per-body state (positions, velocities, element
// rotations, pins, loads) over shared rest data (FemModel), advanced by one
// linearised backward-Euler step:
//
//   M (v+ - v) = dt [ f(x + dt v+, v+) ]   linearised at (x, v):
//   (M + dt C + dt^2 K + dt^2 Kc + dt Dc) v+ = M v + dt (f + fc + Dc v)
//   x+ = x + dt v+
//
// with K the co-rotated stiffness (corotational.h), C = alpha M + beta K the
// Rayleigh damping, f = elastic + gravity + applied forces, and fc, Kc, Dc
// the contact forces and their (positive semi-definite) stiffness and
// damping, added by coupled_step.h, so that stiff contact is integrated
// implicitly too.
// Pinned vertices are held at their targets; the force that holds them is
// reported.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <Eigen/Sparse>
#include <Eigen/SparseCholesky>
#include <memory>
#include <string>
#include <vector>

#include "deformable/corotational.h"
#include "deformable/fem_model.h"

namespace tetcosim {

enum class LinearSolver {
  kConjugateGradient,  // block-Jacobi-preconditioned CG, warm-started from the last
                       // velocity change (the coupled step's solver)
  kCholesky,           // sparse LDL^T, symbolic analysis once
};

enum class SystemProduct {
  kAuto,
  kAssembled,    // a sparse matrix, assembled once per step
  kElementWise,  // matrix-free: A x = M x + sum_e K_e x_e, element by element
};

struct StepSettings {
  double dt = 1e-3;                                        // s, > 0
  Eigen::Vector3d gravity = Eigen::Vector3d(0, 0, -9.81);  // m/s^2
  LinearSolver solver = LinearSolver::kConjugateGradient;
  // CG stops at this residual (of A v+ = b, in N s) relative to the step's
  // impulse b - (1 + dt alpha) M v, what the forces change the momentum by,
  // or to the momentum plus the impulse of the forces from outside the
  // bodies if that is smaller (StepCoupled).
  double cg_tolerance = 1e-6;
  int cg_max_iterations = 1000;
  // Polar decomposition per element and step (ExtractRotation, warm-started
  // from the last step's rotation): at most this many iterations, stopping
  // once the estimated error of the rotation is below rotation_tolerance
  // (radians). A Newton step of angle a leaves an error of about a^2, so
  // with 1e-8 every element whose rotation changed by less than 1e-4 rad
  // in the step takes one step; the elastic forces are then off by about
  // 2 mu V |b_i| 1e-8 (a stress error of 2e-8 mu). Stopping far short of
  // convergence leaves a lagged rotation that injects energy: keep
  // rotation_iterations >= 8.
  int rotation_iterations = 20;
  double rotation_tolerance = 1e-8;
  // For the element loops and the products of bodies of at least 16384
  // tets (within a smaller body a second thread costs more in
  // synchronisation than it saves, measured; StepCoupled shares the smaller
  // bodies out among the threads instead, body by body, from 1024 tets a
  // thread).
  int num_threads = 1;
  // How the conjugate-gradient solve applies the system matrix A (the
  // Cholesky solver always assembles it). Measured (bench/deformable_bench,
  // product 1 and 2): element by element is the faster on one thread for
  // 48000 tets at any iteration count (assembling costs more than the
  // products it saves) and for 2058 tets at few iterations; assembled wins
  // for small bodies whose solves take many iterations (the matrix stays in
  // cache), and for large bodies on several threads whose solves take many
  // iterations (the assembled product splits by rows; the element-wise one
  // runs colour by colour). So kAuto assembles when the last step took 12
  // CG iterations or more and the body has at most 16384 tets or runs on
  // several threads, and goes element-wise otherwise. Results agree to
  // rounding either way; each choice is deterministic.
  SystemProduct system_product = SystemProduct::kAuto;

  // Throws Error for a setting no step can use: dt not finite and > 0,
  // gravity not finite, a tolerance negative or not finite, or fewer than
  // one iteration allowed. (Step and StepCoupled check it: a negative dt
  // stepped backwards in time and reported kOk.)
  void Validate() const;
};

// kDiverged: a non-finite state (the step was undone); kFailed: the step
// could not be completed (MuJoCo raised a fatal error in it: World::Step),
// and the world steps no further.
enum class StepStatus { kOk, kDiverged, kFailed };

struct StepReport {
  StepStatus status = StepStatus::kOk;
  int bad_vertex = -1;    // first vertex with a non-finite state (kDiverged)
  int iterations = 0;     // CG iterations (0 for the direct solver)
  double residual = 0.0;  // relative residual of the linear solve
};

class CoupledStepWorkspace;  // (coupled_step.h)

class DeformableBody {
 public:
  DeformableBody(std::shared_ptr<const FemModel> model, std::string name);
  ~DeformableBody();

  const std::string& name() const { return name_; }
  const FemModel& model() const { return *model_; }
  const TetMesh& mesh() const { return model_->mesh(); }
  int num_vertices() const { return model_->num_vertices(); }

  // State: #V x 3, world frame, metres and metres per second.
  const Positions& positions() const { return x_; }
  const Positions& velocities() const { return v_; }
  Positions& mutable_positions() { return x_; }
  Positions& mutable_velocities() { return v_; }
  // Places the rest shape by X_WB and sets every velocity to v.
  void Reset(const Eigen::Isometry3d& X_WB, const Eigen::Vector3d& v = Eigen::Vector3d::Zero());

  // What a step changes of the body and carries to the next (its state,
  // warm starts and pin forces), and what its caller sets for it (applied
  // forces, pin frames), kept to undo a step: Restore(Save()) leaves the
  // body as if the steps between had not been taken. Save into the same
  // Memory each time allocates only where sizes grow.
  struct Memory {
    Positions x, v, applied;
    std::vector<Eigen::Isometry3d> frames;
    std::vector<Eigen::Quaterniond> rotations;
    Eigen::VectorXd velocity_change;
    int last_iterations = 0;
    std::vector<Eigen::Vector3d> pin_forces;
  };
  void Save(Memory* memory) const;
  void Restore(const Memory& memory);

  // Applied forces (#V x 3, newtons, world frame): kept until changed.
  Positions& applied_forces() { return applied_; }

  // Pins: vertex v held at its current position, or (kinematic) following
  // X_WT * p_T where p_T is its position in a frame T given by X_WT now.
  // PinToFrame adds the frame and returns its index (0, 1, ...); a vertex
  // pinned again is held by its last pin only.
  void Pin(int vertex);
  int PinToFrame(const std::vector<int>& vertices, const Eigen::Isometry3d& X_WT);
  // Moves kinematic frame `frame` for the next step.
  void SetPinFrame(int frame, const Eigen::Isometry3d& X_WT) { frames_[frame] = X_WT; }
  const std::vector<int>& pinned_vertices() const { return pinned_; }
  // The frame of pin i (of pinned_vertices()), or -1 for a fixed pin.
  int pin_frame(size_t i) const { return pin_frame_[i]; }
  // Force the pins applied to each pinned vertex in the last step (N, world).
  const std::vector<Eigen::Vector3d>& pin_forces() const { return pin_forces_; }

  // Advances this body alone (no contacts; see coupled_step.h for bodies in
  // contact) by settings.dt. A non-finite result is not committed: the state
  // stays as it was and the report says kDiverged with the vertex.
  StepReport Step(const StepSettings& settings);

  // Pieces of a step, for stepping bodies coupled by contact
  // (coupled_step.h). PrepareStep assembles the system A v+ = b (without the
  // pins, which the caller prescribes); FinishStep commits v+ (#V x 3, flat)
  // if it and the residual are finite, and takes the pin forces from
  // residual = A_total v+ - b_total. (Eigen's own thread count is the
  // caller's: StepCoupled sets it.)
  void PrepareStep(const StepSettings& settings);
  const Eigen::SparseMatrix<double, Eigen::RowMajor, int>& system_matrix() const { return A_; }
  const Eigen::VectorXd& system_rhs() const { return b_; }
  // The size (N s) of the impulse over the step of the forces from outside
  // the body in system_rhs(): dt (m g + applied force) over its vertices.
  double outside_impulse() const { return outside_impulse_; }
  // Whether the last PrepareStep assembled system_matrix() (else it is
  // stale, and the products are element-wise).
  bool system_assembled() const { return assembled_; }
  // Whether a body of this model runs its element loops and products on
  // several threads with these settings (at least 16384 tets, and
  // StepSettings::num_threads above one); else on the calling thread alone,
  // and then PrepareStep and MultiplySystem of different bodies may run at
  // once on different threads.
  static bool RunsOnSeveralThreads(const FemModel& model, const StepSettings& settings);
  // y = A x (3V each) with the system of the last PrepareStep: assembled, the
  // same as system_matrix() * x but faster, since the three rows of a vertex
  // share their columns (one index and three contiguous x per neighbour);
  // else element by element.
  void MultiplySystem(const double* x, double* y) const;
  // y = (1 + dt alpha) M x: the mass part of A.
  void MultiplyMass(const double* x, double* y) const;
  // The 3 x 3 diagonal block of A for vertex v (for preconditioners).
  const Eigen::Matrix3d& system_diagonal_block(int v) const { return diagonal_blocks_[v]; }
  // Where pinned vertex pinned_vertices()[i] is held now (world frame).
  Eigen::Vector3d PinTarget(size_t i) const;
  // Velocity that takes pinned vertex pinned_vertices()[i] to its target.
  Eigen::Vector3d PinVelocity(size_t i, double dt) const;
  // `iterations`: of the solve that gave v_new (SystemProduct::kAuto).
  StepReport FinishStep(const Eigen::Ref<const Eigen::VectorXd>& v_new,
                        const Eigen::Ref<const Eigen::VectorXd>& residual,
                        const StepSettings& settings, int iterations);
  // The last step's velocity change (3V), a warm start for the next.
  const Eigen::VectorXd& last_velocity_change() const { return delta_v_; }

  // Diagnostics (joules, kg m/s, kg m^2/s; about the world origin).
  double KineticEnergy() const;
  double ElasticEnergy() const;
  double GravitationalEnergy(const Eigen::Vector3d& gravity) const;
  Eigen::Vector3d LinearMomentum() const;
  Eigen::Vector3d AngularMomentum() const;
  Eigen::Vector3d CenterOfMass() const;
  // Velocity of the centre of mass: momentum over mass (m/s).
  Eigen::Vector3d CenterOfMassVelocity() const;
  // Elastic forces at the current positions (#V x 3, newtons), updating the
  // element rotations from their warm start.
  Positions ElasticForces();
  // Element rotations from the last step (#T).
  const std::vector<Eigen::Quaterniond>& rotations() const { return rotations_; }
  // The rotation of element t at the current positions (the polar rotation
  // of its deformation gradient, from the last step's as a warm start): the
  // frame that turns with the material there.
  Eigen::Quaterniond ElementRotation(int t) const;

 private:
  // F of element t at the current positions
  Eigen::Matrix3d ElementDeformation(int t) const;
  using SparseMatrix = Eigen::SparseMatrix<double, Eigen::RowMajor, int>;

  // builds b, the element data of the product and the diagonal blocks; and,
  // with `matrix`, the sparse A
  void Assemble(const StepSettings& settings, bool matrix);
  void MultiplyElementWise(const double* x, double* y) const;
  void AddElementMatrix(int t, const Eigen::Matrix<double, 4, 3>& c, double s,
                        double* values) const;
  void ApplyPins(const StepSettings& settings);
  void Solve(StepReport& report);

  std::shared_ptr<const FemModel> model_;
  std::string name_;
  Positions x_, v_;
  Positions applied_;
  std::vector<Eigen::Quaterniond> rotations_;

  std::vector<int> pinned_;                  // ascending
  std::vector<int> pin_frame_;               // per pin: its frame, or -1 (fixed)
  std::vector<Eigen::Vector3d> pin_target_;  // fixed pins: world; kinematic: in frame T
  std::vector<Eigen::Isometry3d> frames_;    // X_WT of each kinematic frame
  std::vector<Eigen::Vector3d> pin_forces_;

  // the linear system
  bool assembled_ = false;
  int last_iterations_ = 0;  // CG iterations of the last step (kAuto)
  // per batch of elements (FemModel::ElementBatch, in the order of the
  // step's thread count), for the element-wise product: c[r][j] =
  // (R b_{j+1})_r (c_0 = -(c_1 + c_2 + c_3)), and s V mu, s V lambda with
  // s = dt beta + dt^2
  struct BatchSystem {
    Lanes3x3 c;
    Lanes mu_scale;
    Lanes lambda_scale;
  };
  std::vector<BatchSystem> batch_systems_;
  double mass_scale_ = 1.0;  // 1 + dt alpha
  double outside_impulse_ = 0.0;
  int num_threads_ = 1;
  std::vector<Eigen::Matrix3d> diagonal_blocks_;  // per vertex
  SparseMatrix A_;
  Eigen::VectorXd b_, solution_;
  Eigen::VectorXd rhs_, delta_v_;    // A dv = b - A v, and the last dv (warm start)
  std::vector<double> pinned_rows_;  // original rows of pinned DoFs, for pin forces
  Eigen::VectorXd pinned_b_;
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> ldlt_;
  bool ldlt_analyzed_ = false;
  // Step's, with the conjugate gradients (coupled_step.h), made on its first call
  std::unique_ptr<CoupledStepWorkspace> step_workspace_;
};

}  // namespace tetcosim
