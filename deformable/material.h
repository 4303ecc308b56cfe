#pragma once

// Linear elastic material of a deformable body (SI units).

namespace tetcosim {

struct Material {
  double young = 1e5;     // Young's modulus E (Pa), > 0
  double poisson = 0.3;   // Poisson ratio nu, 0 <= nu < 0.5
  double density = 1000;  // kg/m^3, > 0
  // Rayleigh damping: C = alpha M + beta K
  double damping_mass = 0.0;       // alpha (1/s), >= 0
  double damping_stiffness = 0.0;  // beta (s), >= 0

  // Throws Error naming the bad field and its valid range; `where` prefixes
  // the message (a file and line, or a body name).
  void Validate(const char* where) const;
  // Lame parameters: mu = E / (2 (1 + nu)), lambda = E nu / ((1 + nu)(1 - 2 nu)).
  double Mu() const { return young / (2.0 * (1.0 + poisson)); }
  double Lambda() const { return young * poisson / ((1.0 + poisson) * (1.0 - 2.0 * poisson)); }
};

}  // namespace tetcosim
