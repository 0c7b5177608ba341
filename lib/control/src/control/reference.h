// Reference trajectories for the tracking controller: a speed profile along a path.
//
// Speed profile: accelerate at accel_m_s2 from rest until cruise_m_s, then hold. The thesis's
// straight-line experiments (II.6.2, III.2.2) are wheel accelerations alpha = 44, 48 or
// 72 rad/s^2 for 0.5 s: accel = r alpha, cruise = r alpha 0.5 s (straight_profile()).
// Paths, all starting at the origin facing +x (world frame of docs/ARCHITECTURE.md):
//   line:          x = s, y = 0
//   arc:           circle of signed radius R (R > 0 turns left): phi = s/R,
//                  x = R sin(phi), y = R (1 - cos(phi))
//   figure eight:  curvature-continuous: the heading is a sine of the arc length u,
//                  phi = beta sin(tau), tau = 2 pi u / L, so kappa = dphi/du = cos(tau) / R.
//                  beta = j_0,1 = 2.404825557695773 (first zero of J0) closes the curve:
//                  x = beta |R| sum_{k>=1} J_2k(beta)/k sin(2k tau),
//                  y = beta R sum_{k>=0} 2 J_2k+1(beta)/(2k+1) (1 - cos((2k+1) tau))
//                  (Jacobi-Anger; terms to J_9 kept, truncation <= 7.4e-7 |R|).
//                  L = 2 pi beta |R| = 15.11 |R|; 'radius' R is the smallest radius of
//                  curvature (|kappa| <= 1/|R|, at the ends of the lobes); the eight is
//                  2.09 |R| wide and 5.66 |R| long (along y), starts at the bottom of the lower
//                  lobe (facing +x, turning left for R > 0; R < 0 mirrors in y) and crosses
//                  itself at (0, 2.83 R) with heading +-beta (137.8 deg).
// The reference gives the pose, v_r = ds/dt, omega_r = v_r kappa, and their derivatives
// (dv_r/dt, domega_r/dt = dv_r/dt kappa + v_r^2 dkappa/du; dkappa/du = 0 except on the eight).
#ifndef CONTROL_REFERENCE_H
#define CONTROL_REFERENCE_H

#include <stdint.h>

#include <control/fixmath.h>

namespace ctl {

enum class PathKind : uint8_t { kLine = 0, kArc = 1, kFigureEight = 2 };

/// A reference sample (float path).
struct RefSample {
  float x_m, y_m, phi_rad;
  float v_m_s, omega_rad_s;
  float dv_m_s2, domega_rad_s2;
};

/// Constant description of a reference (float).
struct ReferenceSpec {
  PathKind kind;
  float accel_m_s2;   ///< > 0
  float cruise_m_s;   ///< >= 0
  float radius_m;     ///< arc: signed radius (R > 0 turns left); eight: signed smallest radius of
                      ///< curvature (R > 0: first lobe turns left); unused for a line
  /// accel in (0, 20] m/s^2, cruise in [0, 4] m/s, |R| in [0.05, 100] m for arcs and eights.
  constexpr bool valid() const {
    return accel_m_s2 > 0.0f && accel_m_s2 <= 20.0f && cruise_m_s >= 0.0f && cruise_m_s <= 4.0f &&
           (kind == PathKind::kLine ||
            ((kind == PathKind::kArc || kind == PathKind::kFigureEight) &&
             (radius_m >= 0.05f || radius_m <= -0.05f) && radius_m <= 100.0f && radius_m >= -100.0f));
  }
};

/// The thesis's straight line: wheel acceleration alpha for t_acc_s, then constant speed.
ReferenceSpec straight_profile(float wheel_radius_m, float wheel_accel_rad_s2, float t_acc_s = 0.5f);

/// Sample at time t_s >= 0 (t < 0 is treated as 0). Invalid specs give a sample at rest at
/// the origin.
RefSample reference_at(const ReferenceSpec& spec, float t_s);

// ------------------------------------------------------------------------ fixed point
/// Fixed-point reference sample. Formats match the fixed controller's inputs.
struct RefSampleQ {
  int32_t x_q20, y_q20;   ///< m, Q20
  uint32_t phi_b32;       ///< binary angle
  int16_t v_q12;          ///< m/s, Q12
  int16_t omega_q11;      ///< rad/s, Q11
  int16_t dv_q12;         ///< m/s^2, Q12
  int16_t domega_q11;     ///< rad/s^2, Q11
};

/// Figure eight: beta = j_0,1 and J_n(beta), n = 1..9 (scipy.special.jv; J_0(beta) = 1e-16).
constexpr double kEightBeta = 2.4048255576957724;
constexpr double kEightJ(int n) {
  return n == 1 ? 0.5191474972894669 : n == 2 ? 0.4317548070196805 : n == 3 ? 0.19899990535769077
       : n == 4 ? 0.06474666616417792 : n == 5 ? 0.016389243204805847 : n == 6 ? 0.0034048184720278287
       : n == 7 ? 0.0006006883657329531 : n == 8 ? 9.21657867053448e-05 : n == 9 ? 1.2517270977961504e-05 : 0.0;
}

/// Fixed-point reference constants, from a ReferenceSpec at compile time (constexpr).
struct ReferenceSpecQ {
  uint8_t kind;
  int32_t accel_q24;       ///< m/s^2, Q24 (<= 20)
  int32_t cruise_q28;      ///< m/s, Q28 (<= 4)
  int32_t t_ramp_q16;      ///< cruise / accel, s, Q16
  int32_t s_ramp_q20;      ///< distance at the end of the ramp, Q20
  int32_t radius_q20;      ///< signed radius, Q20 (0 for a line)
  int32_t curv_b32_per_q20;///< binary-angle units per Q20 metre = 2^32/(2 pi R 2^20), Q16
  int16_t curv_q12;        ///< 1/R, Q12 (1/m)
  int32_t period_q20;      ///< figure eight: period L = 2 pi beta |R|, Q20
  // figure eight only (0 otherwise):
  int32_t tau_b32_per_q20; ///< binary-angle units of tau per Q20 metre = 2^32/(L 2^20), Q16
  // beta_b32, cx and cy are multiplied by 32768/32767 so that a Q15 sine or cosine of 32767
  // (the table's 1.0) acts as exactly 1 in a plain (x c) >> 15 (what fx::mul_trig does per call).
  int32_t beta_b32;        ///< beta (sign of R) as a binary angle, x 32768/32767
  int32_t cx_q20[4];       ///< beta |R| J_2k(beta)/k, k = 1..4, Q20, x 32768/32767
  int32_t cy_q20[5];       ///< beta R 2 J_2k+1(beta)/(2k+1), k = 0..4, Q20, x 32768/32767
  int32_t cy_sum_q20;      ///< beta R sum 2 J_2k+1(beta)/(2k+1) (the constant part of y), Q20
  bool ok;

  constexpr explicit ReferenceSpecQ(const ReferenceSpec& s)
      : kind(static_cast<uint8_t>(s.kind)),
        accel_q24(s.valid() ? fx::q_const(s.accel_m_s2, 24) : 0),
        cruise_q28(s.valid() ? fx::q_const(s.cruise_m_s, 28) : 0),
        t_ramp_q16(s.valid() ? fx::q_const(s.cruise_m_s / s.accel_m_s2, 16) : 0),
        s_ramp_q20(s.valid() ? fx::q_const(0.5 * s.cruise_m_s * s.cruise_m_s / s.accel_m_s2, 20) : 0),
        radius_q20(s.valid() && s.kind != PathKind::kLine ? fx::q_const(s.radius_m, 20) : 0),
        curv_b32_per_q20(s.valid() && s.kind != PathKind::kLine
                             ? fx::q_const(4096.0 / (6.283185307179586 * s.radius_m), 16) : 0),
        curv_q12(static_cast<int16_t>(s.valid() && s.kind != PathKind::kLine ? fx::q_const(1.0 / s.radius_m, 12) : 0)),
        period_q20(eight(s) ? fx::q_const(6.283185307179586 * kEightBeta * abs_r(s), 20) : 0),
        tau_b32_per_q20(eight(s) ? fx::q_const(4096.0 / (6.283185307179586 * kEightBeta * abs_r(s)), 16) : 0),
        beta_b32(eight(s) ? fx::q_const((s.radius_m > 0 ? kEightBeta : -kEightBeta) / 6.283185307179586 * kTrigOne, 32) : 0),
        cx_q20{cx(s, 0), cx(s, 1), cx(s, 2), cx(s, 3)},
        cy_q20{cy(s, 0, kTrigOne), cy(s, 1, kTrigOne), cy(s, 2, kTrigOne), cy(s, 3, kTrigOne), cy(s, 4, kTrigOne)},
        cy_sum_q20(eight(s) ? fx::q_const(kEightBeta * s.radius_m * 2.0 *
                                              (kEightJ(1) + kEightJ(3) / 3 + kEightJ(5) / 5 + kEightJ(7) / 7 + kEightJ(9) / 9), 20)
                            : 0),
        ok(s.valid()) {}

 private:
  static constexpr bool eight(const ReferenceSpec& s) { return s.valid() && s.kind == PathKind::kFigureEight; }
  static constexpr double abs_r(const ReferenceSpec& s) { return s.radius_m > 0 ? s.radius_m : -s.radius_m; }
  static constexpr int32_t cx(const ReferenceSpec& s, int k) {  // k = 0..3 -> J_2(k+1)/(k+1)
    return eight(s) ? fx::q_const(kEightBeta * abs_r(s) * kEightJ(2 * k + 2) / (k + 1) * kTrigOne, 20) : 0;
  }
  static constexpr int32_t cy(const ReferenceSpec& s, int k, double scale) {
    return eight(s) ? fx::q_const(kEightBeta * s.radius_m * 2.0 * kEightJ(2 * k + 1) / (2 * k + 1) * scale, 20) : 0;
  }
  static constexpr double kTrigOne = 32768.0 / 32767.0;
};

/// Sample at t_ms milliseconds (no float).
RefSampleQ reference_at_q(const ReferenceSpecQ& spec, uint32_t t_ms);

}  // namespace ctl

#endif  // CONTROL_REFERENCE_H
