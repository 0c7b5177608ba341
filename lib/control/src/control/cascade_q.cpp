#include <control/cascade_q.h>

namespace ctl {

namespace {
// |x| < 2^19 (8 N m in Q16): Q16 -> Q12 rounded toward zero (no division: avr-gcc calls
// __divmodsi4 for x / 16).
CTL_INLINE int16_t q16_to_q12_toward_zero(int32_t x) {
  // ceil(x / 16) = floor((x + 15) / 16) for x < 0
  return static_cast<int16_t>(fx::asr<4>(x + (x < 0 ? 15 : 0)));
}
CTL_INLINE int8_t sign32(int32_t x) { return x > 0 ? 1 : (x < 0 ? -1 : 0); }
// Clamp to [-lim, lim] (lim >= 0), *clamped when it acted.
CTL_INLINE int32_t clamp_flag(int32_t x, int32_t lim, bool* clamped) {
  if (x > lim) { *clamped = true; return lim; }
  const int32_t nlim = -lim;
  if (x < nlim) { *clamped = true; return nlim; }
  *clamped = false;
  return x;
}
CTL_INLINE int8_t sign16(int16_t x) { return x > 0 ? 1 : (x < 0 ? -1 : 0); }
// Duty Q15 from u (|u| < 2^31): clamped to +-32767, *sat when |u| >= 32767.
CTL_INLINE int16_t duty_q15(int32_t u, bool* sat) {
  const int16_t d = fx::sat16(u);
  if (d >= fx::kQ15One) { *sat = true; return fx::kQ15One; }
  if (d <= -fx::kQ15One) { *sat = true; return static_cast<int16_t>(-fx::kQ15One); }
  *sat = false;
  return d;
}
// Q20 metres -> Q12 metres, saturated at +-8 m.
CTL_INLINE int16_t q20_to_q12(int32_t x) { return fx::sat16(fx::rshift_round<8>(x)); }
}  // namespace

KinematicOutQ kinematic_law_q(const ControlConfigQ& c, const PoseQ& pose, const RefSampleQ& ref) {
  KinematicOutQ k;
  const int32_t dx = fx::sub_sat32(ref.x_q20, pose.x_q20);
  const int32_t dy = fx::sub_sat32(ref.y_q20, pose.y_q20);
  const int16_t cp = fx::cos_q15(pose.phi_b32), sp = fx::sin_q15(pose.phi_b32);
  const int32_t ex = fx::add_sat32(fx::mul_trig<15>(dx, cp), fx::mul_trig<15>(dy, sp));
  const int32_t ey = fx::sub_sat32(fx::mul_trig<15>(dy, cp), fx::mul_trig<15>(dx, sp));
  k.e_x_q12 = q20_to_q12(ex);
  k.e_y_q12 = q20_to_q12(ey);
  k.e_phi_b32 = static_cast<int32_t>(ref.phi_b32 - pose.phi_b32);
  const uint32_t ephi = static_cast<uint32_t>(k.e_phi_b32);
  const int16_t ce = fx::cos_q15(ephi), se = fx::sin_q15(ephi);
  // v_d = v_r cos e_phi + k_x e_x                      (Q12)
  const int32_t v_d = fx::mul16<15>(ref.v_q12, ce) + fx::mul16<8>(k.e_x_q12, c.k_x_q8);
  // omega_d = omega_r + v_r k_y e_y + k_phi sin e_phi  (Q11)
  const int32_t vey_q12 = fx::mul16<12>(ref.v_q12, k.e_y_q12);
  const int32_t w_d = static_cast<int32_t>(ref.omega_q11) + fx::mul32x16<9>(vey_q12, c.k_y_q8) +
                      fx::mul16<12>(se, c.k_phi_q8);
  k.v_d_q12 = static_cast<int16_t>(fx::clamp32(v_d, c.v_max_q12));
  k.omega_d_q11 = static_cast<int16_t>(fx::clamp32(w_d, c.omega_max_q11));
  return k;
}

ControllerQ::ControllerQ(const ControlConfigQ& cfg) : cfg_(cfg), odo_(cfg.odo) { reset(0, 0, PoseQ{0, 0, 0}); }

void ControllerQ::reset(int32_t enc_r, int32_t enc_l, const PoseQ& p) {
  odo_.reset(enc_r, enc_l, p, cfg_.rate_nominal);  // no division on a first step at the nominal dt
  kin_ = KinematicOutQ{0, 0, 0, 0, 0};
  out_ = InnerOutQ{0, 0, 0, 0, 0, 0, false, false, false, false, OdoStatus::kOk, 0, 0};
  was_r_ = was_l_ = 0;
  const slip::NormalForcesQ nf = slip::normal_forces_q16(cfg_.traction, 0);
  out_.tau_max_r_q16 = slip::tau_max_q16(cfg_.traction, nf.N_r_q16);
  out_.tau_max_l_q16 = slip::tau_max_q16(cfg_.traction, nf.N_l_q16);
  p_ff_q16_ = q_ff_q16_ = 0;
  j_v_q24_ = j_w_q24_ = 0;
  update_limits();
}

// Integrators for dt of 65.5 ms to 0.5 s (rare: a late step): dt in Q16 s = dt_us * 4295 /
// 65536 (error 8e-6 relative), k dt in int16 when it fits, else a 32x16 product.
void ControllerQ::integrate_long_dt(uint32_t dt_us, int16_t e_v, int16_t e_w) {
  const int16_t dt_q16 = static_cast<int16_t>((dt_us * 4295UL) >> 16);  // < 32768 for dt < 0.5 s
  const int32_t kdt_q20 = fx::rshift_round_nc<11>(fx::mul_ss(cfg_.g_il_q15, dt_q16));  // Q31 -> Q20
  const int32_t inc_v = kdt_q20 <= INT16_MAX
      ? fx::rshift_round_nc<8>(fx::mul_ss(e_v, static_cast<int16_t>(kdt_q20)))          // Q32 -> Q24
      : fx::rshift_round<3>(fx::mul32x16_halves<16>(fx::mul_ss(e_v, cfg_.g_il_q15), dt_q16));  // Q27 -> Q24
  j_v_q24_ = fx::clamp32(j_v_q24_ + inc_v, cfg_.jmax_v_q24);  // |J| < 2^30, |inc| <= 2^28
  const int32_t kdt_q24 = fx::rshift_round_nc<10>(fx::mul_ss(cfg_.g_ia_q18, dt_q16));  // Q34 -> Q24
  const int32_t inc_w = kdt_q24 <= INT16_MAX
      ? fx::rshift_round_nc<10>(fx::mul_ss(e_w, static_cast<int16_t>(kdt_q24)))         // Q34 -> Q24
      : fx::rshift_round<4>(fx::mul32x16_halves<16>(fx::mul_ss(e_w, cfg_.g_ia_q18), dt_q16));  // Q28 -> Q24
  j_w_q24_ = fx::clamp32(j_w_q24_ + inc_w, cfg_.jmax_w_q24);
}

const KinematicOutQ& ControllerQ::outer_step(const RefSampleQ& ref) {
  kin_ = kinematic_law_q(cfg_, odo_.pose(), ref);
  // The feed-forward terms change only here: P_ff = (r/2) m_ff dv_ff, Q_ff = (r/2b) I_ff dw_ff.
  p_ff_q16_ = fx::mul16<14>(ref.dv_q12, cfg_.g_ffv_q18);      // Q12*Q18 -> Q16
  q_ff_q16_ = fx::mul16<16>(ref.domega_q11, cfg_.g_ffw_q21);  // Q11*Q21 -> Q16
  // Per-wheel tau_max, refreshed at the outer rate (the load transfer changes slowly):
  // lateral force m_t (v w + d dw_ff), Q16 N, from the latest measured v, w.
  const int16_t v = odo_.v_q12(), w = odo_.omega_q11();
  const int32_t a_lat_q16 = fx::rshift_round<7>(static_cast<int32_t>(v) * w);  // Q23 -> Q16
  const int32_t lat_q16 = fx::add_sat32(fx::mul32x16<8>(a_lat_q16, cfg_.m_t_q8),
                                        fx::mul16<11>(ref.domega_q11, cfg_.mtd_q16));
  const slip::NormalForcesQ nf = slip::normal_forces_q16(cfg_.traction, lat_q16);
  out_.tau_max_r_q16 = slip::tau_max_q16(cfg_.traction, nf.N_r_q16);
  out_.tau_max_l_q16 = slip::tau_max_q16(cfg_.traction, nf.N_l_q16);
  update_limits();
  return kin_;
}

// The clamp's limits (with the clamp on, tau_max less the back-EMF margin: the speed
// measurement's error must not push the delivered torque above tau_max; cascade.h), and the
// duty slope of a wheel clamped at +lim with its advance over half a tick.
void ControllerQ::update_limits() {
  const int32_t r = out_.tau_max_r_q16 - cfg_.margin_q16, l = out_.tau_max_l_q16 - cfg_.margin_q16;
  out_.tau_max_r_q16 = r > 0 ? r : 0;
  out_.tau_max_l_q16 = l > 0 ? l : 0;
  if (!cfg_.clamp_enabled) {
    u_lim0_r_q15_ = u_lim0_l_q15_ = u_lim_r_q15_ = u_lim_l_q15_ = slope_lim_r_q15_ = slope_lim_l_q15_ = 0;
    return;
  }
  // tau_max < 8 N m: Q12 fits (rounded toward zero, as the inner step's torques); the slope is
  // rounded down (a smaller ramp delivers less torque); the advance is the slope over half a tick.
  const int16_t lr = q16_to_q12_toward_zero(out_.tau_max_r_q16), ll = q16_to_q12_toward_zero(out_.tau_max_l_q16);
  slope_lim_r_q15_ = fx::hi16(fx::mul_ss(lr, cfg_.slope_q19));
  slope_lim_l_q15_ = fx::hi16(fx::mul_ss(ll, cfg_.slope_q19));
  u_lim0_r_q15_ = static_cast<int16_t>(fx::mul16<10>(lr, cfg_.inv_stall_q13));
  u_lim0_l_q15_ = static_cast<int16_t>(fx::mul16<10>(ll, cfg_.inv_stall_q13));
  u_lim_r_q15_ = fx::sat16(u_lim0_r_q15_ + (fx::mul_ss(slope_lim_r_q15_, cfg_.tick_ms) >> 1));
  u_lim_l_q15_ = fx::sat16(u_lim0_l_q15_ + (fx::mul_ss(slope_lim_l_q15_, cfg_.tick_ms) >> 1));
}

// The duty of a clamped wheel (|tau| = lim): it gets all of its limit. Its back-EMF term
// follows the speed at the start of the coming tick, i.e. the measured mean speed (that of half
// a tick ago) advanced over half a tick at the clamped torque's acceleration if it was clamped
// with the same sign in the last tick too, and its duty ramps at that acceleration over the tick
// (cascade.h). A wheel not clamped keeps the duty inner_step formed, with no slope. The
// anti-windup saw inner_step's saturation flags: for a clamped wheel the clamp flag decides.
__attribute__((noinline)) void ControllerQ::duty_clamped() {
  // (the two wheels written out: a shared per-wheel helper made this step 40 cycles longer)
  if (out_.clamped_r) {
    const int8_t sg = out_.tau_r_q16 > 0 ? 1 : -1;
    const int16_t b = was_r_ == sg ? u_lim_r_q15_ : u_lim0_r_q15_;
    out_.pwm_r_q15 = duty_q15((sg > 0 ? b : -b) + fx::mul16<12>(odo_.omega_r_q8(), cfg_.inv_no_load_q19), &out_.sat_r);
    out_.slope_r_q15 = sg > 0 ? slope_lim_r_q15_ : static_cast<int16_t>(-slope_lim_r_q15_);
    was_r_ = sg;
  } else {
    out_.slope_r_q15 = 0;
    was_r_ = 0;
  }
  if (out_.clamped_l) {
    const int8_t sg = out_.tau_l_q16 > 0 ? 1 : -1;
    const int16_t b = was_l_ == sg ? u_lim_l_q15_ : u_lim0_l_q15_;
    out_.pwm_l_q15 = duty_q15((sg > 0 ? b : -b) + fx::mul16<12>(odo_.omega_l_q8(), cfg_.inv_no_load_q19), &out_.sat_l);
    out_.slope_l_q15 = sg > 0 ? slope_lim_l_q15_ : static_cast<int16_t>(-slope_lim_l_q15_);
    was_l_ = sg;
  } else {
    out_.slope_l_q15 = 0;
    was_l_ = 0;
  }
}

// inlined into inner_step (and start), so that the inner step costs no call
CTL_INLINE void ControllerQ::command(uint32_t dt_us) {
  const int16_t v = odo_.v_q12(), w = odo_.omega_q11();

  // Velocity errors: e_v Q12 (|v_d| <= 1.4, |v| <= 2.3 m/s: fits), e_w Q10 (|omega_d - omega|
  // can reach 2 x 16 rad/s, beyond Q11).
  const int16_t e_v = fx::sub_sat16(kin_.v_d_q12, v);
  const int16_t e_w = fx::half_diff16(kin_.omega_d_q11, w);

  CTL_PROBE(3);
  // The velocity loop directly in wheel-torque units (Q16 N m): with the split
  // tau_r = (r/2)(F + M/b), tau_l = (r/2)(F - M/b), P = (r/2) F and Q = (r/2b) M give
  // tau_r = P + Q, tau_l = P - Q; every gain below already carries its r/2 or r/2b.
  //   P = (r/2) [m_ff dv_ff - mtd_ff w^2 + k_l e_v + I_v]
  //   Q = (r/2b)[I_ff dw_ff + mtd_ff w v + k_a e_w + I_w]
  // (improved: m_ff = m_eff, I_ff = I_eff, mtd_ff = m_t d; thesis: m_t, I_t, 0)
  // Each product term is below 2^19 (8 N m), the integrators below 64 N m (config check): the
  // sums cannot overflow.
  const int16_t w2_q6 = fx::hi16(fx::mul_ss(w, w));   // <= 256 (rad/s)^2
  const int16_t wv_q7 = fx::hi16(fx::mul_ss(w, v));   // |w v| <= 128
  const int32_t p = p_ff_q16_ - fx::mul16<13>(w2_q6, cfg_.g_c_q23) + fx::mul16<11>(e_v, cfg_.g_l_q15) +
                    fx::rshift_round_nc<8>(j_v_q24_);
  CTL_PROBE(4);
  const int32_t q = q_ff_q16_ + fx::mul16<11>(wv_q7, cfg_.g_cv_q20) + fx::mul16<12>(e_w, cfg_.g_a_q18) +
                    fx::rshift_round_nc<8>(j_w_q24_);
  CTL_PROBE(5);
  const int32_t tau_r = p + q;
  const int32_t tau_l = p - q;

  CTL_PROBE(6);
  const int32_t lim_r = cfg_.clamp_enabled ? out_.tau_max_r_q16 : cfg_.tau_big_q16;
  const int32_t lim_l = cfg_.clamp_enabled ? out_.tau_max_l_q16 : cfg_.tau_big_q16;
  out_.tau_r_q16 = clamp_flag(tau_r, lim_r, &out_.clamped_r);
  out_.tau_l_q16 = clamp_flag(tau_l, lim_l, &out_.clamped_l);

  CTL_PROBE(7);
  // Duty u = tau/stall + dtheta/no_load (Q15), saturated. |tau| <= 10 stall < 8 N m, so the
  // torque fits Q12 int16; it is rounded toward zero so that a torque clamped at tau_max is
  // never rounded above it.
  const int16_t tr_q12 = q16_to_q12_toward_zero(out_.tau_r_q16);
  const int16_t tl_q12 = q16_to_q12_toward_zero(out_.tau_l_q16);
  const int32_t u_r = fx::mul16<10>(tr_q12, cfg_.inv_stall_q13) + fx::mul16<12>(odo_.omega_r_q8(), cfg_.inv_no_load_q19);
  const int32_t u_l = fx::mul16<10>(tl_q12, cfg_.inv_stall_q13) + fx::mul16<12>(odo_.omega_l_q8(), cfg_.inv_no_load_q19);
  out_.pwm_r_q15 = duty_q15(u_r, &out_.sat_r);
  out_.pwm_l_q15 = duty_q15(u_l, &out_.sat_l);

  CTL_PROBE(8);
  // Anti-windup by conditional integration (same rule as the float path): an integrator stops
  // while a limited wheel it drives would be pushed further into the limit (s_i e > 0).
  const int8_t s_r = (out_.clamped_r || out_.sat_r) ? sign32(tau_r) : 0;
  const int8_t s_l = (out_.clamped_l || out_.sat_l) ? sign32(tau_l) : 0;
  if (dt_us > 0 && dt_us < 500000UL) {  // integrate only for 0 < dt < 0.5 s
    CTL_PROBE(9);
    const int8_t sv = sign16(e_v), sw = sign16(e_w);
    const bool block_v = (s_r != 0 && s_r == sv) || (s_l != 0 && s_l == sv);
    const bool block_w = (s_r != 0 && s_r == sw) || (s_l != 0 && s_l == -sw);
    if (dt_us < 65536UL) {
      // dt < 65.5 ms (the firmware's 25 ms): k dt from the gains per microsecond, one 16x16
      // product each; the configuration check keeps k dt within int16 for any such dt.
      // dt changes nearly every step in the firmware: nothing is cached.
      const uint16_t dt16 = static_cast<uint16_t>(dt_us);
      CTL_PROBE(10);
      if (!block_v) {  // J_v += (r/2) k_il dt e_v
        const int16_t kdt_q19 = fx::rshift_round_nc_lo16<15>(fx::mul_us(dt16, cfg_.g_il_us_q34));
        j_v_q24_ = fx::clamp32(j_v_q24_ + fx::rshift_round_nc<7>(fx::mul_ss(e_v, kdt_q19)),  // Q31 -> Q24
                               cfg_.jmax_v_q24);  // |J| < 2^30, |increment| <= 2^23
      }
      if (!block_w) {  // J_w += (r/2b) k_ia dt e_w
        const int16_t kdt_q22 = fx::rshift_round_nc_lo16<15>(fx::mul_us(dt16, cfg_.g_ia_us_q37));
        j_w_q24_ = fx::clamp32(j_w_q24_ + fx::rshift_round_nc<8>(fx::mul_ss(e_w, kdt_q22)),  // Q32 -> Q24
                               cfg_.jmax_w_q24);
      }
    } else {
      integrate_long_dt(dt_us, block_v ? 0 : e_v, block_w ? 0 : e_w);
    }
  }
  CTL_PROBE(0);
  // A clamped wheel: its duty over the coming tick (out of line and last, so that the common
  // step stays as it was; the clamped steps do not integrate).
  if (out_.clamped_r || out_.clamped_l) {
    duty_clamped();
  } else if (was_r_ != 0 || was_l_ != 0) {  // the first step after a clamped one
    out_.slope_r_q15 = out_.slope_l_q15 = 0;
    was_r_ = was_l_ = 0;
  }
}

const InnerOutQ& ControllerQ::start(int32_t enc_r, int32_t enc_l, const PoseQ& p, const RefSampleQ& ref0) {
  reset(enc_r, enc_l, p);
  if (!cfg_.ok) {
    out_.odo = OdoStatus::kBadConfig;
    return out_;
  }
  outer_step(ref0);
  out_.odo = OdoStatus::kOk;
  command(0);  // from rest: the wheel speeds are 0 after the reset; dt 0 integrates nothing
  return out_;
}

const InnerOutQ& ControllerQ::inner_step(int32_t enc_r, int32_t enc_l, uint32_t dt_us) {
  if (!cfg_.ok) {  // refuse to drive with a configuration that did not convert
    out_ = InnerOutQ{0, 0, 0, 0, 0, 0, false, false, false, false, OdoStatus::kBadConfig, 0, 0};

    return out_;
  }
  CTL_PROBE(1);
  out_.odo = odo_.update_deferred(enc_r, enc_l, dt_us);  // pose arc: in the outer step
  CTL_PROBE(2);
  command(dt_us);
  return out_;
}

}  // namespace ctl
