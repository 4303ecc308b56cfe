#include "deformable/material.h"

#include <cmath>
#include <string>

#include "mesh/error.h"

namespace tetcosim {

void Material::Validate(const char* where) const {
  auto fail = [&](const std::string& message) { throw Error(std::string(where) + ": " + message); };
  if (!std::isfinite(young) || young <= 0.0) {
    fail("young (Young's modulus) must be a positive number of pascals, e.g. 1e5");
  }
  if (!std::isfinite(poisson) || poisson < 0.0 || poisson >= 0.5) {
    fail("poisson must be in [0, 0.5); 0.5 would make the material incompressible");
  }
  if (!std::isfinite(density) || density <= 0.0) fail("density must be positive (kg/m^3)");
  if (!std::isfinite(damping_mass) || damping_mass < 0.0 || !std::isfinite(damping_stiffness) ||
      damping_stiffness < 0.0) {
    fail("damping coefficients must be >= 0");
  }
}

}  // namespace tetcosim
