#include <slipmodel/traction.h>

namespace slip {

NormalForces normal_forces(const RobotParams& p, double lat_force_n) {
  NormalForces n;
  n.N_c = detail::n_c_of(p);                       // II.29
  const double wheels = p.m_t() * p.g - n.N_c;     // II.27
  const double transfer = p.h * lat_force_n / (2.0 * p.b);  // II.28, half the difference
  n.N_r = 0.5 * wheels + transfer;
  n.N_l = 0.5 * wheels - transfer;
  if (n.N_r < 0.0) { n.N_r = 0.0; n.N_l = wheels; }
  if (n.N_l < 0.0) { n.N_l = 0.0; n.N_r = wheels; }
  return n;
}

double tau_max_per_newton(const RobotParams& p) {
  const double mt = p.m_t();
  return p.mu_s * (2.0 * p.I_wy + mt * p.r * p.r) / (mt * p.r);
}

double tau_max(const RobotParams& p, double N_n) {
  if (!(N_n > 0.0)) return 0.0;  // also catches NaN
  return tau_max_per_newton(p) * N_n;
}

namespace {
int32_t sat32(int64_t x) {
  if (x > INT32_MAX) return INT32_MAX;
  if (x < INT32_MIN) return INT32_MIN;
  return static_cast<int32_t>(x);
}
// (a * b) >> 24 with round-half-up, saturated.
int32_t mul_q24(int32_t a, int32_t b_q24) {
  const int64_t prod = static_cast<int64_t>(a) * static_cast<int64_t>(b_q24);
  return sat32((prod + (static_cast<int64_t>(1) << 23)) >> 24);
}
}  // namespace

NormalForcesQ normal_forces_q16(const TractionQ& q, int32_t lat_force_q16) {
  NormalForcesQ n;
  n.N_c_q16 = q.n_c_q16;
  const int64_t transfer = mul_q24(lat_force_q16, q.lat_gain_q24);
  int64_t r = static_cast<int64_t>(q.n_wheel0_q16) + transfer;
  int64_t l = static_cast<int64_t>(q.n_wheel0_q16) - transfer;
  if (r < 0) { r = 0; l = q.n_wheels_q16; }
  if (l < 0) { l = 0; r = q.n_wheels_q16; }
  n.N_r_q16 = sat32(r);
  n.N_l_q16 = sat32(l);
  return n;
}

int32_t tau_max_q16(const TractionQ& q, int32_t N_q16) {
  if (N_q16 <= 0) return 0;
  const int64_t prod = static_cast<int64_t>(N_q16) * static_cast<int64_t>(q.k_tau_q24);
  const int64_t tau = (prod >> 24) - 1;  // floor, then one LSB lower (see the header)
  return tau < 0 ? 0 : sat32(tau);
}

}  // namespace slip
