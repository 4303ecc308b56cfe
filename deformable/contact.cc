#include "deformable/contact.h"

#include <cmath>

namespace tetcosim {

double DefaultContactPressureStiffness(const FemModel& model) {
  return 10.0 * model.material().young / model.characteristic_length();
}

ContactLinearization LinearizeContact(std::span<DeformableBody* const> bodies,
                                      const ContactPoint& contact, const ContactSettings& settings,
                                      FrictionLaw law, const Eigen::Vector3d& slide) {
  const Eigen::Vector3d& r = contact.direction;
  // velocities and masses of both sides at the point
  ContactLinearization out;
  out.rigid_velocity.setZero();
  Eigen::Vector3d v_a = contact.velocity_a;
  double m_a = contact.mass_a;
  if (contact.body_a >= 0) {
    const DeformableBody& a = *bodies[contact.body_a];
    v_a = a.velocities().row(contact.vertex_a).transpose();
    m_a = a.model().masses()[contact.vertex_a];
  } else if (contact.rigid_point < 0) {
    out.rigid_velocity += contact.velocity_a;
  }
  Eigen::Vector3d v_b = contact.velocity_b;
  double m_b = contact.mass_b;
  if (contact.body_b >= 0) {
    const DeformableBody& b = *bodies[contact.body_b];
    v_b.setZero();
    m_b = 0.0;
    for (int i = 0; i < 4; ++i) {
      int vertex = b.mesh().tets()(contact.tet_b, i);
      v_b += contact.barycentric_b[i] * b.velocities().row(vertex).transpose();
      m_b += contact.barycentric_b[i] * b.model().masses()[vertex];
    }
  } else if (contact.rigid_point < 0) {
    out.rigid_velocity -= contact.velocity_b;
  }
  out.rigid_velocity += contact.arc;
  // reduced mass (a side without mass is infinitely heavy)
  const double mass = m_a > 0.0 && m_b > 0.0 ? m_a * m_b / (m_a + m_b) : std::max(m_a, m_b);
  const double k = contact.stiffness;
  const double c = 2.0 * contact.damping_ratio * std::sqrt(k * std::max(mass, 0.0));
  out.relative_velocity = v_a - v_b;
  const double v_n = out.relative_velocity.dot(r);
  const bool approaching = v_n < 0.0;
  const double f_n = std::max(0.0, k * contact.depth - (approaching ? c * v_n : 0.0));
  const Eigen::Vector3d v_t = out.relative_velocity - v_n * r;
  const Eigen::Matrix3d rr = r * r.transpose();
  const Eigen::Matrix3d tangential = Eigen::Matrix3d::Identity() - rr;
  out.stiffness = k * rr;
  out.damping = (approaching ? c : 0.0) * rr;
  switch (law) {
    case FrictionLaw::kSticking: {
      const double k_t = settings.stick_stiffness * k;
      const double c_t = 2.0 * contact.damping_ratio * std::sqrt(k_t * std::max(mass, 0.0));
      out.force = f_n * r - k_t * (tangential * contact.stick) - c_t * v_t;
      out.stiffness += k_t * tangential;
      out.damping += c_t * tangential;
      return out;
    }
    case FrictionLaw::kSliding:
      out.force = f_n * r + slide;
      return out;
    case FrictionLaw::kSmooth:
      break;
  }
  const double slip =
      std::sqrt(v_t.squaredNorm() + settings.slip_velocity * settings.slip_velocity);
  const double friction_gain = contact.friction * f_n / slip;
  out.force = f_n * r - friction_gain * v_t;
  out.damping += friction_gain * tangential;
  return out;
}

void AddHalfSpaceContacts(int index, const DeformableBody& body, const Eigen::Vector3d& normal,
                          double offset, double kappa, double friction,
                          std::vector<ContactPoint>& contacts, ContactArea rule) {
  const Eigen::VectorXd& areas = body.model().contact_areas();
  for (int v = 0; v < body.num_vertices(); ++v) {
    double depth = offset - normal.dot(body.positions().row(v).transpose());
    if (depth <= 0.0) continue;
    ContactPoint contact;
    contact.body_a = index;
    contact.vertex_a = v;
    contact.depth = depth;
    contact.direction = normal;
    contact.stiffness =
        kappa * ContactAreaOf(rule, body.model().mesh(), body.positions(), v, normal, areas[v]);
    contact.friction = friction;
    contacts.push_back(contact);
  }
}

}  // namespace tetcosim
