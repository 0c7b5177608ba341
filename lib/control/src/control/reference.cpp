#include <control/reference.h>

#include <math.h>

namespace ctl {

ReferenceSpec straight_profile(float wheel_radius_m, float wheel_accel_rad_s2, float t_acc_s) {
  return ReferenceSpec{PathKind::kLine, wheel_radius_m * wheel_accel_rad_s2,
                       wheel_radius_m * wheel_accel_rad_s2 * t_acc_s, 0.0f};
}

RefSample reference_at(const ReferenceSpec& sp, float t_s) {
  RefSample o{0, 0, 0, 0, 0, 0, 0};
  if (!sp.valid()) return o;
  if (!(t_s > 0.0f)) t_s = 0.0f;  // also maps NaN to 0
  const float t_ramp = sp.cruise_m_s / sp.accel_m_s2;
  float s, v, dv;
  if (t_s < t_ramp) {
    v = sp.accel_m_s2 * t_s;
    s = 0.5f * v * t_s;
    dv = sp.accel_m_s2;
  } else {
    v = sp.cruise_m_s;
    s = 0.5f * sp.cruise_m_s * t_ramp + sp.cruise_m_s * (t_s - t_ramp);
    dv = 0.0f;
  }
  o.v_m_s = v;
  o.dv_m_s2 = dv;
  if (sp.kind == PathKind::kLine) {
    o.x_m = s;
    return o;
  }
  float rad = sp.radius_m;  // signed: > 0 turns left
  float u = s;
  if (sp.kind == PathKind::kFigureEight) {
    const float rabs = fabsf(rad);
    const float period = 6.28318530717959f * rabs;
    const float k = floorf(s / period);
    u = s - k * period;
    if (fmodf(k, 2.0f) != 0.0f) rad = -rad;  // odd circles turn the other way
  }
  const float phi = u / rad;
  o.x_m = rad * sinf(phi);
  o.y_m = rad * (1.0f - cosf(phi));
  o.phi_rad = phi;
  // wrap to [-pi, pi)
  o.phi_rad = phi - 6.28318530717959f * floorf((phi + 3.14159265358979f) / 6.28318530717959f);
  o.omega_rad_s = v / rad;
  o.domega_rad_s2 = dv / rad;
  return o;
}

RefSampleQ reference_at_q(const ReferenceSpecQ& sp, uint32_t t_ms) {
  RefSampleQ o{0, 0, 0, 0, 0, 0, 0};
  if (!sp.ok) return o;
  if (t_ms > 32000000UL) t_ms = 32000000UL;  // 8.9 h: t_q16 stays below 2^31
  // t in Q16 s: t_ms * 65.536 = t_ms * 65 + t_ms * 549 / 1024 (error 1e-6 relative).
  const int32_t t_q16 = static_cast<int32_t>(t_ms * 65UL + ((t_ms * 549UL) >> 10));
  int32_t s_q20, v_q24, dv_q24;
  if (t_q16 < sp.t_ramp_q16) {
    const int64_t v = (static_cast<int64_t>(sp.accel_q24) * t_q16) >> 16;       // Q24
    v_q24 = static_cast<int32_t>(v);
    s_q20 = static_cast<int32_t>((v * t_q16) >> 21);                            // v t / 2
    dv_q24 = sp.accel_q24;
  } else {
    v_q24 = sp.cruise_q28 >> 4;
    const int64_t s = static_cast<int64_t>(sp.s_ramp_q20) +
                      ((static_cast<int64_t>(sp.cruise_q28) * (t_q16 - sp.t_ramp_q16)) >> 24);
    s_q20 = s > INT32_MAX ? INT32_MAX : static_cast<int32_t>(s);
    dv_q24 = 0;
  }
  o.v_q12 = fx::sat16(fx::rshift_round<12>(v_q24));
  o.dv_q12 = fx::sat16(fx::rshift_round<12>(dv_q24));
  if (sp.kind == static_cast<uint8_t>(PathKind::kLine)) {
    o.x_q20 = s_q20;
    return o;
  }
  int32_t u_q20 = s_q20;
  bool flip = false;
  if (sp.kind == static_cast<uint8_t>(PathKind::kFigureEight)) {
    const int32_t k = s_q20 / sp.period_q20;  // s >= 0
    u_q20 = s_q20 - k * sp.period_q20;
    flip = (k & 1) != 0;
  }
  // phi = u / R as a binary angle (wraps modulo 2 pi by construction).
  uint32_t phi = static_cast<uint32_t>((static_cast<int64_t>(u_q20) * sp.curv_b32_per_q20) >> 16);
  int32_t rad_q20 = sp.radius_q20;
  int16_t curv_q12 = sp.curv_q12;
  if (flip) {
    phi = 0U - phi;
    rad_q20 = -rad_q20;
    curv_q12 = static_cast<int16_t>(-curv_q12);
  }
  o.phi_b32 = phi;
  o.x_q20 = fx::mul_trig<15>(rad_q20, fx::sin_q15(phi));
  o.y_q20 = rad_q20 - fx::mul_trig<15>(rad_q20, fx::cos_q15(phi));
  o.omega_q11 = fx::sat16(fx::mul16<13>(o.v_q12, curv_q12));
  o.domega_q11 = fx::sat16(fx::mul16<13>(o.dv_q12, curv_q12));
  return o;
}

}  // namespace ctl
