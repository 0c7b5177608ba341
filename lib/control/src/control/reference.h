// Reference trajectories for the tracking controller: a speed profile along a path.
//
// Speed profile: accelerate at accel_m_s2 from rest until cruise_m_s, then hold. The thesis's
// straight-line experiments (II.6.2, III.2.2) are wheel accelerations alpha = 44, 48 or
// 72 rad/s^2 for 0.5 s: accel = r alpha, cruise = r alpha 0.5 s (straight_profile()).
// Paths, all starting at the origin facing +x (world frame of docs/ARCHITECTURE.md):
//   line:          x = s, y = 0
//   arc:           circle of signed radius R (R > 0 turns left): phi = s/R,
//                  x = R sin(phi), y = R (1 - cos(phi))
//   figure eight:  a left circle of radius R (centre (0, R)) then a right circle (centre
//                  (0, -R)), each a full turn, repeated; the curvature switches sign at the
//                  origin, where both circles are tangent to +x.
// The reference gives the pose, v_r = ds/dt, omega_r = v_r kappa, and their derivatives
// (dv_r/dt, domega_r/dt = dv_r/dt kappa; the curvature jump of the eight is not differentiated).
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
  float radius_m;     ///< arc: signed radius (R > 0 turns left); eight: |R|; unused for a line
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
  int32_t period_q20;      ///< figure eight: one circle, 2 pi |R|, Q20
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
        period_q20(s.valid() && s.kind == PathKind::kFigureEight
                       ? fx::q_const(6.283185307179586 * (s.radius_m > 0 ? s.radius_m : -s.radius_m), 20) : 0),
        ok(s.valid()) {}
};

/// Sample at t_ms milliseconds (no float).
RefSampleQ reference_at_q(const ReferenceSpecQ& spec, uint32_t t_ms);

}  // namespace ctl

#endif  // CONTROL_REFERENCE_H
