#include <control/drive.h>

#include <math.h>

namespace ctl {

namespace {
float clampf(float x, float lim) {
  if (!(x == x)) return 0.0f;  // NaN -> 0
  return x > lim ? lim : (x < -lim ? -lim : x);
}
int16_t clamp16(int16_t x, int16_t lim) { return x > lim ? lim : (x < -lim ? static_cast<int16_t>(-lim) : x); }
// x * num / 1000, rounded, without a division: the rounded 32x16 product with num / 1000 in Q16
// (4.096 and 2.048: 268435 and 134218, off by 0.46 and 0.27 in 65536: the nearest integer for
// every |x| in the Drive ranges whose exact result is not within 0.07 of a half)
template <int32_t NUM>
int16_t scale_round(int16_t x) {
  return fx::sat16(fx::mul32x16<16>(static_cast<int32_t>((NUM * 65536LL + 500) / 1000), x));
}
}  // namespace

RefSample DriveReference::step(float v_target, float w_target) {
  const float dv = clampf(v_target - v_, lim_.accel_m_s2 * dt_);
  const float dw = clampf(w_target - w_, lim_.alpha_rad_s2 * dt_);
  RefSample o{x_, y_, phi_, v_, w_, dv / dt_, dw / dt_};
  const float v1 = v_ + dv, w1 = w_ + dw;
  const float ds = 0.5f * (v_ + v1) * dt_, dphi = 0.5f * (w_ + w1) * dt_;
  const float mid = phi_ + 0.5f * dphi;
  x_ += ds * cosf(mid);
  y_ += ds * sinf(mid);
  phi_ += dphi;
  // wrap to [-pi, pi) (the binary angle of the fixed path wraps by itself)
  phi_ -= 6.28318530717959f * floorf((phi_ + 3.14159265358979f) / 6.28318530717959f);
  v_ = v1;
  w_ = w1;
  return o;
}

int16_t drive_v_q12(int16_t v_mm_s) { return scale_round<4096>(v_mm_s); }
int16_t drive_omega_q11(int16_t omega_mrad_s) { return scale_round<2048>(omega_mrad_s); }

RefSampleQ DriveReferenceQ::step(const DriveConfigQ& c, int16_t v_target_q12, int16_t omega_target_q11) {
  const int16_t dv = clamp16(fx::sub_sat16(v_target_q12, v_q12_), c.dv_step_q12);
  const int16_t dw = clamp16(fx::sub_sat16(omega_target_q11, w_q11_), c.dw_step_q11);
  RefSampleQ o;
  o.x_q20 = x_q20_;
  o.y_q20 = y_q20_;
  o.phi_b32 = phi_b32_;
  o.v_q12 = v_q12_;
  o.omega_q11 = w_q11_;
  o.dv_q12 = fx::sat16(static_cast<int32_t>(dv) * c.inv_dt_hz);
  o.domega_q11 = fx::sat16(static_cast<int32_t>(dw) * c.inv_dt_hz);
  const int16_t v1 = fx::add_sat16(v_q12_, dv), w1 = fx::add_sat16(w_q11_, dw);
  const int32_t sv = static_cast<int32_t>(v_q12_) + v1, sw = static_cast<int32_t>(w_q11_) + w1;
  const int32_t ds_q20 = fx::mul32x16<12>(sv, c.ds_q12);
  // |sw| <= 2 * 30720 and dphi_int < 17000: the product fits int32
  const int32_t dphi_b32 = sw * c.dphi_int + fx::asr<15>(sw * c.dphi_frac_q15);
  const uint32_t mid = phi_b32_ + static_cast<uint32_t>(fx::asr<1>(dphi_b32));
  x_q20_ = fx::add_sat32(x_q20_, fx::mul_trig<15>(ds_q20, fx::cos_q15(mid)));
  y_q20_ = fx::add_sat32(y_q20_, fx::mul_trig<15>(ds_q20, fx::sin_q15(mid)));
  phi_b32_ += static_cast<uint32_t>(dphi_b32);
  v_q12_ = v1;
  w_q11_ = w1;
  return o;
}

}  // namespace ctl
