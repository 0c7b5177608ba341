// The control cascade in fixed point (integer only; the AVR inner/outer loop).
// Same equations as cascade.h; formats (Qn = value * 2^n):
//   positions Q20 m (int32), heading binary angle (uint32), position errors Q12 m (int16, +-8 m)
//   v Q12 m/s, omega Q11 rad/s, wheel speeds Q8 rad/s (int16)
//   dv_ff Q12 m/s^2, domega_ff Q11 rad/s^2 (int16)
//   the velocity loop works in wheel-torque units: P = (r/2) F and Q = (r/2b) M, Q16 N m (int32),
//   so that the split is tau_r = P + Q, tau_l = P - Q (no multiply); its integrators are kept
//   as (r/2) I_v and (r/2b) I_w in Q24 N m (integ_v_q16()/integ_w_q16() convert back to N, N m)
//   wheel torques and tau_max Q16 N m (int32, the format of slip::tau_max_q16); duty Q15 (int16)
// Every intermediate is saturated; no input in range can overflow (see test_control_fixed).
#ifndef CONTROL_CASCADE_Q_H
#define CONTROL_CASCADE_Q_H

#include <stdint.h>

#include <control/cascade.h>
#include <control/fixmath.h>
#include <control/odometry.h>
#include <control/reference.h>
#include <slipmodel/traction.h>

namespace ctl {

/// The inner loop's nominal sample period (the thesis's 25 ms), the default of ControlConfigQ's
/// nominal_dt_us.
static const uint32_t kNominalInnerDtUs = 25000;

/// Fixed-point configuration, built from the float one by a constexpr constructor, so that the
/// firmware can fold it at compile time when its ControlConfig is a constant expression.
struct ControlConfigQ {
  OdometryConfigQ odo;
  slip::TractionQ traction;
  int16_t k_x_q8, k_y_q8, k_phi_q8;  // 1/s, 1/m^2, 1/s
  int16_t k_l_q8;                    // N s/m
  int16_t k_a_q12;                   // N m s
  int16_t k_il_q8;                   // N/m
  int16_t k_ia_q12;                  // N m
  int16_t m_ff_q12;                  // feed-forward mass, kg (< 8)
  int16_t I_ff_q17;                  // feed-forward yaw inertia, kg m^2 (< 0.25)
  int16_t m_t_q8;                    // kg
  int16_t mtd_q16;                   // m_t d, kg m
  int16_t mtd_q18;                   // m_t d, kg m (< 0.125)
  int16_t inv_b_q8;                  // 1/b, 1/m
  int16_t half_r_q16;                // r/2, m
  int16_t inv_stall_q13;             // 1/stall, 1/(N m) (stall > 0.25 N m)
  int16_t inv_no_load_q19;           // 1/no_load, s/rad (no_load > 16 rad/s: a fitted back-EMF ratio up to 2)
  int16_t v_max_q12, omega_max_q11;
  int32_t integ_max_v_q16, integ_max_w_q16;
  int32_t tau_big_q16;               // sanity limit when the clamp is off (10 stall)
  // The velocity loop in wheel-torque units (P = (r/2) F, Q = (r/2b) M):
  int16_t g_l_q15;                   // (r/2) k_l             N m s/m
  int16_t g_a_q18;                   // (r/2b) k_a            N m s
  int16_t g_c_q23;                   // (r/2) mtd_ff          kg m^2 (m_t d; 0: thesis)
  int16_t g_cv_q20;                  // (r/2b) mtd_ff         kg m^2 / m
  int16_t g_ffv_q18;                 // (r/2) m_ff            kg m
  int16_t g_ffw_q21;                 // (r/2b) I_ff           kg m^2
  int16_t g_il_q15;                  // (r/2) k_il            N m/m
  int16_t g_ia_q18;                  // (r/2b) k_ia           N m
  int16_t g_il_us_q34;               // (r/2) k_il 1e-6 (k dt for dt in us; < 2^14: k dt fits Q19)
  int16_t g_ia_us_q37;               // (r/2b) k_ia 1e-6 (< 2^14: k dt fits Q22)
  int32_t jmax_v_q24, jmax_w_q24;    // integrator bounds (r/2) I_v,max and (r/2b) I_w,max, N m
  int32_t two_over_r_q16, two_b_over_r_q16;  // to report the integrators in N and N m
  bool clamp_enabled;
  bool ok;
  /// The wheel-rate state (the 1/dt division) for the nominal dt, from the same code as the
  /// run-time division (OdometryConfigQ::rate_for): ControllerQ::reset() starts from it, so a
  /// first step with dt within +-63 us of the nominal dt does not divide.
  RateQ rate_nominal;
  // Torque->PWM of a clamped wheel over the coming tick (cascade.h): duty slope per ms per N m
  // (rolling acceleration / no-load speed), the clamp's margin below tau_max, the nominal tick.
  int16_t slope_q19;                 // duty/ms per N m
  int16_t margin_q16;                // N m
  uint8_t tick_ms;                   // nominal tick in ms (the prediction covers half of it)

  /// nominal_dt_us: the inner loop's sample period (0: no precomputed rate).
  constexpr explicit ControlConfigQ(const ControlConfig& c, uint32_t nominal_dt_us = kNominalInnerDtUs)
      : odo(OdometryConfig{static_cast<float>(c.robot.r), static_cast<float>(c.robot.b), c.counts_per_rev}),
        traction(slip::traction_q(c.robot)),
        k_x_q8(q16c(c.gains.k_x, 8)), k_y_q8(q16c(c.gains.k_y, 8)), k_phi_q8(q16c(c.gains.k_phi, 8)),
        k_l_q8(q16c(c.gains.k_l, 8)), k_a_q12(q16c(c.gains.k_a, 12)),
        k_il_q8(q16c(c.gains.k_il, 8)), k_ia_q12(q16c(c.gains.k_ia, 12)),
        m_ff_q12(q16c(c.m_ff_kg, 12)), I_ff_q17(q16c(c.I_ff_kgm2, 17)),
        m_t_q8(q16c(c.robot.m_t(), 8)), mtd_q16(q16c(c.robot.m_t() * c.robot.d, 16)),
        mtd_q18(q16c(c.robot.m_t() * c.robot.d, 18)),
        inv_b_q8(q16c(1.0 / c.robot.b, 8)), half_r_q16(q16c(c.robot.r / 2.0, 16)),
        inv_stall_q13(q16c(1.0 / c.motor.stall_nm, 13)),
        inv_no_load_q19(q16c(1.0 / c.motor.no_load_rad_s, 19)),
        v_max_q12(q16c(c.v_max_m_s, 12)), omega_max_q11(q16c(c.omega_max_rad_s, 11)),
        integ_max_v_q16(fx::q_const(c.integ_max_n, 16)), integ_max_w_q16(fx::q_const(c.integ_max_nm, 16)),
        tau_big_q16(fx::q_const(10.0 * c.motor.stall_nm, 16)),
        g_l_q15(q16c(c.robot.r / 2.0 * c.gains.k_l, 15)),
        g_a_q18(q16c(c.robot.r / (2.0 * c.robot.b) * c.gains.k_a, 18)),
        g_c_q23(q16c(c.robot.r / 2.0 * c.mtd_ff_kg_m, 23)),
        g_cv_q20(q16c(c.robot.r / (2.0 * c.robot.b) * c.mtd_ff_kg_m, 20)),
        g_ffv_q18(q16c(c.robot.r / 2.0 * c.m_ff_kg, 18)),
        g_ffw_q21(q16c(c.robot.r / (2.0 * c.robot.b) * c.I_ff_kgm2, 21)),
        g_il_q15(q16c(c.robot.r / 2.0 * c.gains.k_il, 15)),
        g_ia_q18(q16c(c.robot.r / (2.0 * c.robot.b) * c.gains.k_ia, 18)),
        g_il_us_q34(q16c(c.robot.r / 2.0 * c.gains.k_il * 1e-6, 34)),
        g_ia_us_q37(q16c(c.robot.r / (2.0 * c.robot.b) * c.gains.k_ia * 1e-6, 37)),
        jmax_v_q24(fx::q_const(c.robot.r / 2.0 * c.integ_max_n, 24)),
        jmax_w_q24(fx::q_const(c.robot.r / (2.0 * c.robot.b) * c.integ_max_nm, 24)),
        two_over_r_q16(fx::q_const(2.0 / c.robot.r, 16)),
        two_b_over_r_q16(fx::q_const(2.0 * c.robot.b / c.robot.r, 16)),
        clamp_enabled(c.clamp_enabled),
        ok(OdometryConfigQ::ok_range(OdometryConfig{static_cast<float>(c.robot.r), static_cast<float>(c.robot.b),
                                                    c.counts_per_rev}) &&
           fits16(c.gains.k_x, 8) && fits16(c.gains.k_y, 8) && fits16(c.gains.k_phi, 8) &&
           fits16(c.gains.k_l, 8) && fits16(c.gains.k_a, 12) && fits16(c.gains.k_il, 8) &&
           fits16(c.gains.k_ia, 12) && fits16(c.m_ff_kg, 12) && fits16(c.I_ff_kgm2, 17) &&
           fits16(c.robot.m_t() * c.robot.d, 18) && fits16(1.0 / c.robot.b, 8) &&
           fits16(1.0 / c.motor.stall_nm, 13) && c.motor.stall_nm * 10.0 < 7.99 && fits16(1.0 / c.motor.no_load_rad_s, 19) &&
           fits16(c.v_max_m_s, 12) && fits16(c.omega_max_rad_s, 11) && c.gains.k_x >= 0 &&
           c.gains.k_y >= 0 && c.gains.k_phi >= 0 && c.gains.k_l >= 0 && c.gains.k_a >= 0 &&
           c.gains.k_il >= 0 && c.gains.k_ia >= 0 &&
           fits16(c.robot.r / 2.0 * c.gains.k_l, 15) && fits16(c.robot.r / (2.0 * c.robot.b) * c.gains.k_a, 18) &&
           fits16(c.robot.r / 2.0 * c.mtd_ff_kg_m, 23) &&
           fits16(c.robot.r / (2.0 * c.robot.b) * c.mtd_ff_kg_m, 20) &&
           fits16(c.robot.r / 2.0 * c.m_ff_kg, 18) && fits16(c.robot.r / (2.0 * c.robot.b) * c.I_ff_kgm2, 21) &&
           fits16(c.robot.r / 2.0 * c.gains.k_il, 15) && fits16(c.robot.r / (2.0 * c.robot.b) * c.gains.k_ia, 18) &&
           c.robot.r / 2.0 * c.gains.k_il * 1e-6 * fx::pow2(34) < 16384.0 &&
           c.robot.r / (2.0 * c.robot.b) * c.gains.k_ia * 1e-6 * fx::pow2(37) < 16384.0 &&
           c.robot.r / 2.0 * c.integ_max_n < 64.0 && c.robot.r / (2.0 * c.robot.b) * c.integ_max_nm < 64.0 &&
           2.0 / c.robot.r < 32000.0 && 2.0 * c.robot.b / c.robot.r < 32000.0 &&
           fits16(c.wheel_accel_per_nm * 1e-3 / c.motor.no_load_rad_s, 19)),
        rate_nominal(odo.rate_for(nominal_dt_us)),
        slope_q19(q16c(c.wheel_accel_per_nm * 1e-3 / c.motor.no_load_rad_s, 19)),
        margin_q16(q16c(c.clamp_enabled ? c.margin_nm : 0.0, 16)),
        tick_ms(static_cast<uint8_t>((nominal_dt_us + 500u) / 1000u > 255u ? 255u : (nominal_dt_us + 500u) / 1000u)) {}

  static constexpr bool fits16(double v, int shift) {
    return v * fx::pow2(shift) < 32767.0 && v * fx::pow2(shift) > -32768.0;
  }
  static constexpr int16_t q16c(double v, int shift) {
    return fits16(v, shift) ? static_cast<int16_t>(fx::q_const(v, shift)) : 0;
  }
};

struct KinematicOutQ {
  int16_t e_x_q12, e_y_q12;  ///< m, Q12 (saturated at +-8 m)
  int32_t e_phi_b32;         ///< binary angle, signed
  int16_t v_d_q12, omega_d_q11;
};

/// Fixed-point kinematic law (II.40-II.44, corrected frame).
KinematicOutQ kinematic_law_q(const ControlConfigQ& c, const PoseQ& pose, const RefSampleQ& ref);

struct InnerOutQ {
  int16_t pwm_r_q15, pwm_l_q15;       ///< duty at the start of the coming tick
  int32_t tau_r_q16, tau_l_q16;       ///< after the clamp
  int32_t tau_max_r_q16, tau_max_l_q16;  ///< the clamp's limit: slip::tau_max_q16 less the back-EMF margin
  bool clamped_r, clamped_l, sat_r, sat_l;
  OdoStatus odo;
  int16_t slope_r_q15, slope_l_q15;   ///< duty added per millisecond over the coming tick (clamped wheels)
};

class ControllerQ {
 public:
  explicit ControllerQ(const ControlConfigQ& cfg);
  /// Start from pose p with the encoders reading (enc_r, enc_l); the wheel-rate state starts
  /// from the configuration's rate_nominal, so a first step at the nominal dt (+-63 us) does not
  /// divide.
  void reset(int32_t enc_r, int32_t enc_l, const PoseQ& p);
  /// Start of an experiment, at its first inner tick (reference time 0): reset(enc_r, enc_l, p),
  /// the outer step with ref0 (the reference at t = 0), and the first command at once, from
  /// rest (wheel speeds 0; nothing integrated). The inner steps follow one period apart, the
  /// outer step after every second one (the schedule of the firmware and lib/closedloop).
  const InnerOutQ& start(int32_t enc_r, int32_t enc_l, const PoseQ& p, const RefSampleQ& ref0);
  /// Outer loop (50 ms). Call after the inner step of the same tick (fresh pose).
  const KinematicOutQ& outer_step(const RefSampleQ& ref);
  /// Inner loop (25 ms): counts and dt in microseconds.
  const InnerOutQ& inner_step(int32_t enc_r, int32_t enc_l, uint32_t dt_us);

  const OdometryQ& odometry() const { return odo_; }
  const KinematicOutQ& kinematic() const { return kin_; }
  const InnerOutQ& inner() const { return out_; }
  /// The velocity-loop integrators I_v (N) and I_w (N m), Q16 (converted from the wheel-torque
  /// units they are kept in; within +-integ_max).
  int32_t integ_v_q16() const { return j_to_q16(j_v_q24_, cfg_.two_over_r_q16, cfg_.integ_max_v_q16); }
  int32_t integ_w_q16() const { return j_to_q16(j_w_q24_, cfg_.two_b_over_r_q16, cfg_.integ_max_w_q16); }

 private:
  ControlConfigQ cfg_;
  OdometryQ odo_;
  KinematicOutQ kin_;
  InnerOutQ out_;
  void integrate_long_dt(uint32_t dt_us, int16_t e_v, int16_t e_w);
  static int32_t j_to_q16(int32_t j_q24, int32_t scale_q16, int32_t lim_q16) {
    const int64_t x = (static_cast<int64_t>(j_q24) * scale_q16) / 16777216;
    return static_cast<int32_t>(x > lim_q16 ? lim_q16 : (x < -lim_q16 ? -lim_q16 : x));
  }

  int32_t p_ff_q16_, q_ff_q16_;    // (r/2) m_ff dv_ff, (r/2b) I_ff dw_ff: from the outer step
  int32_t j_v_q24_, j_w_q24_;      // (r/2) I_v, (r/2b) I_w
  // A wheel clamped at +lim (update_limits(), at the outer rate): its duty's torque term lim/stall
  // alone (first clamped tick) and with the speed advance over half a tick (clamped before, same
  // sign), and its slope; the sign (+1, -1, 0) the wheel was clamped with in the last tick.
  int16_t u_lim0_r_q15_, u_lim0_l_q15_, u_lim_r_q15_, u_lim_l_q15_;
  int16_t slope_lim_r_q15_, slope_lim_l_q15_;
  int8_t was_r_, was_l_;
  void update_limits();
  void duty_clamped();
  /// The velocity loop, split, clamp and duty on the current odometry; integrates over dt_us
  /// (0: nothing).
  void command(uint32_t dt_us);
};

}  // namespace ctl

#endif  // CONTROL_CASCADE_Q_H
