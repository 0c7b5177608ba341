#include <slipmodel/motor.h>

namespace slip {

namespace {
double clamp(double x, double lo, double hi) {
  if (x != x) return 0.0;  // NaN
  return x < lo ? lo : (x > hi ? hi : x);
}
}  // namespace

double motor_torque_nm(const MotorParams& m, double u, double dtheta_rad_s) {
  return motor_torque_nm(m, u, dtheta_rad_s, MotorImperfections());
}

double motor_torque_nm(const MotorParams& m, double u, double dtheta_rad_s,
                       const MotorImperfections& x) {
  if (!(m.supply_v > 0.0) || !(m.no_load_rad_s > 0.0) || !(m.stall_nm > 0.0)) return 0.0;
  double v = clamp(u, -1.0, 1.0) * (m.supply_v - x.drop_v);
  const double mag = (v < 0.0 ? -v : v) - x.deadband_v;
  v = mag <= 0.0 ? 0.0 : (v < 0.0 ? -mag : mag);
  const double w = dtheta_rad_s != dtheta_rad_s ? 0.0 : dtheta_rad_s;
  const double tau = m.stall_nm * (v / m.supply_v - x.ke_ratio * w / m.no_load_rad_s);
  return clamp(tau, -m.stall_nm, m.stall_nm);
}

double motor_duty_for_torque(const MotorParams& m, double tau_nm, double dtheta_rad_s) {
  if (!(m.no_load_rad_s > 0.0) || !(m.stall_nm > 0.0)) return 0.0;
  return clamp(tau_nm / m.stall_nm + dtheta_rad_s / m.no_load_rad_s, -1.0, 1.0);
}

MotorParams motor_as_driven(const MotorParams& m, const MotorImperfections& x) {
  if (!(x.ke_ratio > 0.0) || !(x.drop_v < m.supply_v) || !(m.supply_v > 0.0)) return m;
  MotorParams o = m;
  const double f = (m.supply_v - x.drop_v) / m.supply_v;
  o.stall_nm = m.stall_nm * f;
  o.no_load_rad_s = m.no_load_rad_s * f / x.ke_ratio;
  return o;
}

double motor_current_a(const MotorParams& m, double tau_nm) {
  if (!(m.stall_nm > 0.0)) return 0.0;
  return tau_nm * m.stall_a / m.stall_nm;
}

}  // namespace slip
