// Normal forces (II.27-II.29 with the lateral load transfer of II.28) and the no-slip torque
// limit tau_max (II.50-II.51), in floating point and in fixed point.
//
// Sign conventions (docs/ARCHITECTURE.md): body x forward, body y to the left; the right wheel is
// at -b, the left at +b. `lat_force_n` is F_latr + F_latl, the sum of the lateral ground forces on
// the two wheels, positive towards body +y (left). A left turn at speed needs a positive lateral
// force, which loads the outer (right) wheel: N_r - N_l = h (F_latr + F_latl) / b   (II.28).
#ifndef SLIPMODEL_TRACTION_H
#define SLIPMODEL_TRACTION_H

#include <stdint.h>

#include <slipmodel/params.h>

namespace slip {

struct NormalForces {
  double N_r;  ///< right wheel, N
  double N_l;  ///< left wheel, N
  double N_c;  ///< caster, N
};

/// II.27-II.29: N_c = m_t g d / (d + e); N_r + N_l = m_t g - N_c; N_r - N_l = h L / b with
/// L = lat_force_n. A wheel normal force never goes below zero: past lift-off the whole wheel
/// load (m_t g - N_c) sits on the other wheel (the model does not describe tipping).
NormalForces normal_forces(const RobotParams& p, double lat_force_n = 0.0);

/// Torque-to-limit ratio of II.51, tau_max / N = mu_s (2 I_wy + m_t r^2) / (m_t r), in m.
double tau_max_per_newton(const RobotParams& p);

/// II.51: the largest wheel torque that keeps the wheel from slipping in straight-line
/// acceleration, for a wheel normal force N_n (N). Returns N m (>= 0 for N_n >= 0).
double tau_max(const RobotParams& p, double N_n);

// ---------------------------------------------------------------------------------------------
// Fixed point. Forces and torques are Q16.16 (int32_t, LSB 2^-16 N or N m, range +-32768).
// Coefficients that are small numbers are Q8.24. The coefficients are computed from the
// parameters by a constexpr function, so firmware can fold them at compile time and the
// run-time path (normal_forces_q16, tau_max_q16) uses integers only.
//
// Error bound (see README, tested in test_slipmodel_traction): for |lat_force| <= 256 N,
// N <= 64 N and tau_max/N <= 1 m,
//   |N_q16 - N|     <= 3 * 2^-17 N      (~2.3e-5 N)
//   |tau_q16 - tau| <= 2^-16 N m        (~1.53e-5 N m)
// against the double-precision functions above with the same parameters.
// ---------------------------------------------------------------------------------------------

struct TractionQ {
  int32_t n_wheel0_q16;  ///< (m_t g - N_c) / 2: each wheel's load with no lateral force, Q16.16 N
  int32_t n_wheels_q16;  ///< m_t g - N_c: both wheels together, Q16.16 N
  int32_t n_c_q16;       ///< N_c, Q16.16 N
  int32_t lat_gain_q24;  ///< h / (2 b), Q8.24 (dimensionless)
  int32_t k_tau_q24;     ///< tau_max_per_newton, Q8.24 m
};

struct NormalForcesQ {
  int32_t N_r_q16;
  int32_t N_l_q16;
  int32_t N_c_q16;
};

namespace detail {
constexpr int32_t sat_round_q(double x) {
  return x >= 2147483647.0 ? INT32_MAX
         : x <= -2147483648.0 ? INT32_MIN
         : static_cast<int32_t>(x >= 0.0 ? x + 0.5 : x - 0.5);
}
constexpr double n_c_of(const RobotParams& p) { return p.m_t() * p.g * p.d / (p.d + p.e); }
}  // namespace detail

/// Fixed-point coefficients for `p` (constexpr: fold at compile time on the AVR).
constexpr TractionQ traction_q(const RobotParams& p) {
  return TractionQ{
      detail::sat_round_q((p.m_t() * p.g - detail::n_c_of(p)) * 0.5 * 65536.0),
      detail::sat_round_q((p.m_t() * p.g - detail::n_c_of(p)) * 65536.0),
      detail::sat_round_q(detail::n_c_of(p) * 65536.0),
      detail::sat_round_q(p.h / (2.0 * p.b) * 16777216.0),
      detail::sat_round_q(p.mu_s * (2.0 * p.I_wy + p.m_t() * p.r * p.r) / (p.m_t() * p.r) *
                          16777216.0)};
}

/// Integer-only II.27-II.29; lat_force_q16 is F_latr + F_latl in Q16.16 N. Saturates.
NormalForcesQ normal_forces_q16(const TractionQ& q, int32_t lat_force_q16);

/// Integer-only II.51: tau_max in Q16.16 N m for a normal force N_q16 (negative N gives 0).
/// Rounded DOWN and one LSB (1.5e-5 N m) lower still, so that it is never above the float
/// tau_max of the same lateral force: the roundings of N_q16 (<= 1.5 LSB of N) and k_tau_q24
/// add at most 0.55 LSB for N <= 256 N. The limit is a knife edge (the plant slips as soon as
/// the applied torque exceeds it by any amount), so a slip-avoiding limit must err low.
int32_t tau_max_q16(const TractionQ& q, int32_t N_q16);

}  // namespace slip

#endif  // SLIPMODEL_TRACTION_H
