#include <slipmodel/rolling.h>

namespace slip {

double rolling_mass_kg(const RobotParams& p) { return p.m_t() + 2.0 * p.I_wy / (p.r * p.r); }

double rolling_yaw_inertia_kgm2(const RobotParams& p) {
  return p.I_o() + 2.0 * p.I_wy * p.b * p.b / (p.r * p.r);
}

RollingAccel pure_rolling_accel(const RobotParams& p, double v_m_s, double omega_rad_s,
                                double tau_r_nm, double tau_l_nm) {
  RollingAccel a;
  const double md = p.m_t() * p.d;
  a.dv_m_s2 = ((tau_r_nm + tau_l_nm) / p.r + md * omega_rad_s * omega_rad_s) / rolling_mass_kg(p);
  a.domega_rad_s2 = (p.b * (tau_r_nm - tau_l_nm) / p.r - md * omega_rad_s * v_m_s) /
                    rolling_yaw_inertia_kgm2(p);
  return a;
}

}  // namespace slip
