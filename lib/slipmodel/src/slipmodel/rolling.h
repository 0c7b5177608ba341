// Pure-rolling dynamics (the consistent form of II.14), referred to the axle centre o.
//
// Derived in lib/slipmodel/README.md from the same Newton-Euler equations as the slip plant,
// with both wheel contacts stuck (no longitudinal or lateral slip) and the wheels' spin
// inertia I_wy included:
//   (m_t + 2 I_wy / r^2) dv/dt         = (tau_r + tau_l) / r + m_t d omega^2
//   (I_o + 2 I_wy b^2 / r^2) domega/dt = b (tau_r - tau_l) / r - m_t d omega v
// with I_o = I_t + m_t d^2. For d = 0 and I_wy = 0 this is the thesis's II.14 with
// tau_L = (tau_r + tau_l)/r and tau_A = b (tau_r - tau_l)/r.
#ifndef SLIPMODEL_ROLLING_H
#define SLIPMODEL_ROLLING_H

#include <slipmodel/params.h>

namespace slip {

/// Effective translational mass under pure rolling, m_t + 2 I_wy / r^2 (kg).
double rolling_mass_kg(const RobotParams& p);
/// Effective yaw inertia about o under pure rolling, I_o + 2 I_wy b^2 / r^2 (kg m^2).
double rolling_yaw_inertia_kgm2(const RobotParams& p);

struct RollingAccel {
  double dv_m_s2;        ///< forward acceleration of o
  double domega_rad_s2;  ///< yaw acceleration
};

/// Accelerations of the pure-rolling model for wheel torques tau_r, tau_l at speed v, yaw rate
/// omega. The wheel speeds follow from v, omega: dtheta = (v +- b omega) / r.
RollingAccel pure_rolling_accel(const RobotParams& p, double v_m_s, double omega_rad_s,
                                double tau_r_nm, double tau_l_nm);

}  // namespace slip

#endif  // SLIPMODEL_ROLLING_H
