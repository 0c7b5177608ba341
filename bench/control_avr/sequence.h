// The fixed-point call sequence timed by bench.cpp, shared with host_check.cpp so that the
// AVR build (inline-assembly multiplies, byte-move shifts) and the host build (plain C) can be
// compared output for output: both print a checksum of every fixed-point output.
#ifndef BENCH_CONTROL_AVR_SEQUENCE_H
#define BENCH_CONTROL_AVR_SEQUENCE_H

#include <stdint.h>

#include <control/cascade_q.h>
#include <control/reference.h>

namespace bench {

static const uint8_t kRuns = 64;

// Encoder counts that follow the arc reference the benchmark tracks (0.5 m/s^2 ramp to
// 0.4 m/s on R = 0.6 m: about 95 and 66 counts per 25 ms at cruise), with +-2 counts of jitter
// and, at steps 40..43, a disturbance (the right wheel jumps ahead) that drives the clamp and
// the duty into their limits. So both the integrating and the limited paths are timed.
inline int16_t inc_r_at(uint8_t j) {
  const int16_t base = static_cast<int16_t>(95 * (j < 32 ? j : 32) / 32);
  return static_cast<int16_t>(base + ((j * 7) & 3) - 1 + (j >= 40 && j < 44 ? 120 : 0));
}
inline int16_t inc_l_at(uint8_t j) {
  return static_cast<int16_t>(66 * (j < 32 ? j : 32) / 32 + ((j * 5) & 3) - 2);
}
inline int32_t enc_r_at(uint8_t i) {
  int32_t c = 0;
  for (uint8_t j = 1; j <= i; ++j) c += inc_r_at(j);
  return c;
}
inline int32_t enc_l_at(uint8_t i) {
  int32_t c = 0;
  for (uint8_t j = 1; j <= i; ++j) c += inc_l_at(j);
  return c;
}
/// The inner step's dt as the firmware measures it: 25 ms with microsecond jitter, so the
/// cached wheel-rate reciprocal and integrator gains are recomputed on (nearly) every call.
inline uint32_t dt_us_at(uint8_t i) { return 25000UL + ((i * 7U) % 9U) - 4U; }

/// The outer step (and the reference sample) runs after every second inner step, as in the
/// firmware (25/50 ms); the pose arcs of both inner steps are integrated in it.
inline bool outer_due(uint8_t i) { return (i & 1) == 0; }

inline uint32_t mix(uint32_t h, uint32_t v) { return (h ^ v) * 16777619UL + 0x9E3779B9UL; }

// The pose is read only after an outer step (reading it integrates the queued arcs, which
// would otherwise leave the timed outer step with fewer arcs than in the firmware).
inline uint32_t checksum_step(uint32_t h, const ctl::ControllerQ& q, const ctl::RefSampleQ& r, uint8_t i) {
  const ctl::InnerOutQ& o = q.inner();
  h = mix(h, static_cast<uint16_t>(o.pwm_r_q15));
  h = mix(h, static_cast<uint16_t>(o.pwm_l_q15));
  h = mix(h, static_cast<uint16_t>(o.slope_r_q15));
  h = mix(h, static_cast<uint16_t>(o.slope_l_q15));
  h = mix(h, static_cast<uint32_t>(o.tau_r_q16));
  h = mix(h, static_cast<uint32_t>(o.tau_l_q16));
  h = mix(h, static_cast<uint32_t>(o.tau_max_r_q16));
  if (outer_due(i)) {
    h = mix(h, static_cast<uint32_t>(q.odometry().pose().x_q20));
    h = mix(h, static_cast<uint32_t>(q.odometry().pose().y_q20));
    h = mix(h, q.odometry().pose().phi_b32);
  }
  h = mix(h, static_cast<uint16_t>(q.kinematic().v_d_q12));
  h = mix(h, static_cast<uint16_t>(q.kinematic().omega_d_q11));
  h = mix(h, static_cast<uint32_t>(r.x_q20));
  h = mix(h, r.phi_b32);
  h = mix(h, static_cast<uint32_t>(q.integ_v_q16()));
  return h;
}

// The figure-eight reference sampled over more than one lap (L = 9.07 m at 0.4 m/s: 22.7 s)
// for its own timing row and checksum (every field of every sample).
constexpr ctl::ReferenceSpec kEightSpec{ctl::PathKind::kFigureEight, 0.5f, 0.4f, 0.6f};
inline uint32_t eight_t_ms(uint8_t i) { return 400UL * i; }
inline uint32_t checksum_ref(uint32_t h, const ctl::RefSampleQ& r) {
  h = mix(h, static_cast<uint32_t>(r.x_q20));
  h = mix(h, static_cast<uint32_t>(r.y_q20));
  h = mix(h, r.phi_b32);
  h = mix(h, static_cast<uint16_t>(r.v_q12));
  h = mix(h, static_cast<uint16_t>(r.omega_q11));
  h = mix(h, static_cast<uint16_t>(r.dv_q12));
  return mix(h, static_cast<uint16_t>(r.domega_q11));
}

// sin_q15 and cos_q15 (inline assembly on the AVR) over every table point and quadrant edge
// (angles k 2^20 +- 1) and 4,096 pseudo-random angles: a third checksum.
inline uint32_t checksum_trig() {
  uint32_t h = 0, x = 1;
  for (uint16_t k = 0; k < 4096; ++k) {
    const uint32_t e = static_cast<uint32_t>(k) << 20;
    x = x * 1103515245UL + 12345UL;
    const uint32_t a[4] = {e, e - 1, e + 1, x ^ (x << 9)};
    for (uint8_t j = 0; j < 4; ++j) {
      h = mix(h, static_cast<uint16_t>(ctl::fx::sin_q15(a[j])));
      h = mix(h, static_cast<uint16_t>(ctl::fx::cos_q15(a[j])));
    }
  }
  return h;
}

// Lines whose constants are exact in float and double (so the AVR's and the host's
// ReferenceSpecQ agree), slow enough not to saturate Q20 within the 8.9 h clamp of t: 0.0625 m/s
// after a 0.125 s ramp, and after a ramp of 4096 s. Sampled over 8.9 h: a fourth checksum (the
// profile's products and time conversion at long times).
constexpr ctl::ReferenceSpec kSlowLines[2] = {{ctl::PathKind::kLine, 0.5f, 0.0625f, 0.0f},
                                              {ctl::PathKind::kLine, 1.0f / 65536, 0.0625f, 0.0f}};
inline uint32_t checksum_long() {
  uint32_t h = 0;
  for (uint8_t k = 0; k < 2; ++k) {
    const ctl::ReferenceSpecQ q(kSlowLines[k]);
    for (uint8_t i = 0; i <= 64; ++i) h = checksum_ref(h, ctl::reference_at_q(q, 500000UL * i + 12345UL * (i & 7)));
  }
  return h;
}

// Every field of the fixed configuration, in order, as int32 (the AVR builds its configuration
// in 32-bit float at start-up, the host in double, so the constants may differ by an LSB; the
// host replay therefore uses the AVR's values).
#define BENCH_CFG_FIELDS(X)                                                                     \
  X(odo.ds_per_count_q44) X(odo.dphi_per_count_b32) X(odo.dphi_per_count_frac)                  \
  X(odo.wheel_rate_q11) X(odo.half_r_q16) X(odo.r_over_2b_q15) X(odo.inv_rate_q32) X(odo.ok)                        \
  X(traction.n_wheel0_q16) X(traction.n_wheels_q16) X(traction.n_c_q16)                         \
  X(traction.lat_gain_q24) X(traction.k_tau_q24) X(k_x_q8) X(k_y_q8) X(k_phi_q8) X(k_l_q8)      \
  X(k_a_q12) X(k_il_q8) X(k_ia_q12) X(m_ff_q12) X(I_ff_q17) X(m_t_q8) X(mtd_q16) X(mtd_q18)   \
  X(inv_b_q8) X(half_r_q16) X(inv_stall_q13) X(inv_no_load_q19) X(v_max_q12) X(omega_max_q11)   \
  X(integ_max_v_q16) X(integ_max_w_q16) X(tau_big_q16) X(g_l_q15) X(g_a_q18) X(g_c_q23)          \
  X(g_cv_q20) X(g_ffv_q18) X(g_ffw_q21) X(g_il_q15) X(g_ia_q18) X(g_il_us_q34) X(g_ia_us_q37)       \
  X(jmax_v_q24) X(jmax_w_q24)     \
  X(two_over_r_q16) X(two_b_over_r_q16) X(clamp_enabled) X(ok)                                 \
  X(rate_nominal.dt_us) X(rate_nominal.per_count_q11) X(rate_nominal.div_q10) X(rate_nominal.slope_q12)
#define BENCH_REF_FIELDS(X)                                                                     \
  X(kind) X(accel_q24) X(cruise_q28) X(t_ramp_q16) X(s_ramp_q20) X(radius_q20)                  \
  X(curv_b32_per_q20) X(curv_q12) X(period_q20) X(tau_b32_per_q20) X(beta_b32)                 \
  X(cx_q20[0]) X(cx_q20[1]) X(cx_q20[2]) X(cx_q20[3]) X(cy_q20[0]) X(cy_q20[1]) X(cy_q20[2])    \
  X(cy_q20[3]) X(cy_q20[4]) X(cy_sum_q20) X(ok)

}  // namespace bench

#endif
