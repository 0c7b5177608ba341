#include <control/odometry.h>

#include <math.h>
#include <stddef.h>

namespace ctl {

namespace {
const float kPi = 3.14159265358979f;
// detail::rate_slope's product at run time (OdometryConfigQ::rate_for uses plain C).
struct FxRateOps {
  static CTL_INLINE uint32_t mul(uint16_t a, uint16_t b) { return fx::mul_uu(a, b); }
};
const float kTwoPi = 6.28318530717959f;

int32_t count_step(int32_t now, int32_t last, bool* jumped) {
  // Modulo-2^32 difference: correct across int32 wrap-around.
  int32_t d = static_cast<int32_t>(static_cast<uint32_t>(now) - static_cast<uint32_t>(last));
  if (d > kMaxStepCounts || d < -kMaxStepCounts) {
    *jumped = true;
    d = d > 0 ? kMaxStepCounts : -kMaxStepCounts;
  }
  return d;
}
}  // namespace

float wrap_pi(float a) {
  if (!(a == a)) return 0.0f;  // NaN guard
  if (a >= -kPi && a < kPi) return a;
  a = fmodf(a + kPi, kTwoPi);
  if (a < 0.0f) a += kTwoPi;
  return a - kPi;
}

// ---------------------------------------------------------------- float
Odometry::Odometry(const OdometryConfig& cfg)
    : cfg_(cfg),
      rad_per_count_(cfg.counts_per_rev > 0 ? kTwoPi / static_cast<float>(cfg.counts_per_rev) : 0.0f) {
  reset(0, 0, Pose{0.0f, 0.0f, 0.0f});
}

void Odometry::reset(int32_t enc_r, int32_t enc_l, const Pose& p) {
  last_r_ = enc_r;
  last_l_ = enc_l;
  pose_ = p;
  pose_.phi_rad = wrap_pi(p.phi_rad);
  w_r_ = w_l_ = v_ = w_ = 0.0f;
}

OdoStatus Odometry::update(int32_t enc_r, int32_t enc_l, float dt_s) {
  if (!cfg_.valid()) return OdoStatus::kBadConfig;
  bool jumped = false;
  const int32_t dn_r = count_step(enc_r, last_r_, &jumped);
  const int32_t dn_l = count_step(enc_l, last_l_, &jumped);
  last_r_ = enc_r;
  last_l_ = enc_l;

  const float dth_r = static_cast<float>(dn_r) * rad_per_count_;
  const float dth_l = static_cast<float>(dn_l) * rad_per_count_;
  const float r = cfg_.wheel_radius_m;
  const float ds = 0.5f * r * (dth_r + dth_l);
  const float dphi = r * (dth_r - dth_l) / (2.0f * cfg_.half_track_m);
  const float half = 0.5f * dphi;
  // sinc by series near 0 (error < half^6/5040 < 2e-22 there), sin/x elsewhere.
  const float h2 = half * half;
  const float sinc = (h2 < 1.0e-4f) ? 1.0f - h2 * (1.0f / 6.0f) * (1.0f - h2 * 0.05f) : sinf(half) / half;
  const float chord = ds * sinc;
  const float mid = pose_.phi_rad + half;
  pose_.x_m += chord * cosf(mid);
  pose_.y_m += chord * sinf(mid);
  pose_.phi_rad = wrap_pi(pose_.phi_rad + dphi);

  OdoStatus st = jumped ? OdoStatus::kCountJump : OdoStatus::kOk;
  if (dt_s > 0.0f && dt_s < 1.0e30f) {
    w_r_ = dth_r / dt_s;
    w_l_ = dth_l / dt_s;
  } else {
    w_r_ = w_l_ = 0.0f;
    st = OdoStatus::kBadDt;
  }
  v_ = 0.5f * r * (w_r_ + w_l_);
  w_ = r * (w_r_ - w_l_) / (2.0f * cfg_.half_track_m);
  return st;
}

// ---------------------------------------------------------------- fixed point
OdometryQ::OdometryQ(const OdometryConfigQ& cfg) : cfg_(cfg) { reset(0, 0, PoseQ{0, 0, 0}); }

void OdometryQ::reset(int32_t enc_r, int32_t enc_l, const PoseQ& p, const RateQ& rate) {
  last_r_ = enc_r;
  last_l_ = enc_l;
  pose_ = p;
  phi_frac_ = 0;
  x_frac_ = y_frac_ = 0;
  n_pending_ = 0;
  last_dt_us_ = rate.dt_us;
  div_ = rate;
  rate_q10_ = rate.div_q10;
  w_r_q8_ = w_l_q8_ = v_q12_ = w_q11_ = 0;
}

OdoStatus OdometryQ::update(int32_t enc_r, int32_t enc_l, uint32_t dt_us) {
  const OdoStatus st = update_deferred(enc_r, enc_l, dt_us);
  if (n_pending_ != 0) integrate_pending();
  return st;
}

// The exact rate for dt (a division), and the slope d rate / d dt = -rate / dt for the
// first-order updates of update_deferred(): rate(dt0 + e) = rate0 (1 - e/dt0 + (e/dt0)^2 - ...);
// dropping the square costs rate0 (e/dt0)^2 <= 65535 (63/13540)^2 = 1.4 units of Q10 at the
// extreme (dt0 = 13.5 ms), 0.23 units at 25 ms, plus 0.5 of rounding. The slope rate0/dt0 =
// rate0^2 / (wheel_rate_q11 / 2) needs no second division.
void OdometryQ::set_dt(uint32_t dt_us) {
#if defined(__AVR__)
  if ((dt_us & 0xFFFF8000UL) == 0) {
    // dt < 32.8 ms and (checked in the block) dt > wheel_rate_q11 / 2^17 (13.5 ms at the robot's
    // slip::kEncoderPpr counts per turn), the firmware's range, in one block of call-clobbered registers (nothing saved,
    // no call): the 17-step division of fx::div17(), then exactly the values of set_dt_wide():
    // the quotient q has at most 17 bits, so rate_div = (q + 1) >> 1 truncated to 16 bits (0
    // for q = 2^17 - 1, as there), and the slope floor(floor(r^2 / 2^16) inv / 2^16) from
    // exact 16x16 products (high words with every carry).
    div_.dt_us = dt_us;
    constexpr size_t kOffRpc = offsetof(OdometryQ, div_) + offsetof(RateQ, per_count_q11);
    constexpr size_t kOffDiv = offsetof(OdometryQ, div_) + offsetof(RateQ, div_q10);
    constexpr size_t kOffSlope = offsetof(OdometryQ, div_) + offsetof(RateQ, slope_q12);
    static_assert(kOffRpc <= 63, "adiw range");
    static_assert(offsetof(OdometryQ, rate_q10_) - kOffRpc <= 62 && kOffSlope - kOffRpc <= 62 && kOffDiv - kOffRpc <= 62 &&
                  offsetof(OdometryQ, cfg_) + offsetof(OdometryConfigQ, wheel_rate_q11) <= 60 &&
                  offsetof(OdometryQ, cfg_) + offsetof(OdometryConfigQ, inv_rate_q32) <= 62, "ldd/std displacement");
    uint16_t rem, lo, d = static_cast<uint16_t>(dt_us), inv;
    uint8_t z;
    OdometryQ* self = this;
    __asm__ volatile(
        // k = wheel_rate_q11; out of range unless k_hi >> 1 < d
        "ldd %A[rem], Z+%[o_k]+2\n\tldd %B[rem], Z+%[o_k]+3\n\t"
        "movw %A[lo], %A[rem]\n\tlsr %B[lo]\n\tror %A[lo]\n\t"
        "cp %A[lo], %A[d]\n\tcpc %B[lo], %B[d]\n\tbrcs 0f\n\t"
        "clr %[z]\n\tinc %[z]\n\trjmp 9f\n"
        "0:\n\t"
        "ldd %A[lo], Z+%[o_k]\n\tldd %B[lo], Z+%[o_k]+1\n\t"
        "ldd %A[inv], Z+%[o_inv]\n\tldd %B[inv], Z+%[o_inv]+1\n\t"
        // division: quotient q = (z : lo), as in fx::div17()
        "cp %A[rem], %A[d]\n\tcpc %B[rem], %B[d]\n\tbrcs 1f\n\tsub %A[rem], %A[d]\n\tsbc %B[rem], %B[d]\n"
        "1:\n\t"
        ".rept 16\n\t"
        "rol %A[lo]\n\trol %B[lo]\n\trol %A[rem]\n\trol %B[rem]\n\t"
        "cp %A[rem], %A[d]\n\tcpc %B[rem], %B[d]\n\tbrcs 3f\n\tsub %A[rem], %A[d]\n\tsbc %B[rem], %B[d]\n"
        "3:\n\t"
        ".endr\n\t"
        "rol %A[lo]\n\trol %B[lo]\n\tsbc %[z], %[z]\n\tinc %[z]\n\tcom %A[lo]\n\tcom %B[lo]\n\t"
        // div_.per_count_q11 = q
        "adiw r30, %[o_rpc]\n\t"
        "st Z, %A[lo]\n\tstd Z+1, %B[lo]\n\tstd Z+2, %[z]\n\tstd Z+3, __zero_reg__\n\t"
        // r = (q + 1) >> 1 (16 bits) -> div_.div_q10, rate_q10_
        "sec\n\tadc %A[lo], __zero_reg__\n\tadc %B[lo], __zero_reg__\n\tadc %[z], __zero_reg__\n\t"
        "lsr %[z]\n\tror %B[lo]\n\tror %A[lo]\n\t"
        "std Z+%[o_rd], %A[lo]\n\tstd Z+%[o_rd]+1, %B[lo]\n\t"
        "std Z+%[o_rq], %A[lo]\n\tstd Z+%[o_rq]+1, %B[lo]\n\t"
        "clr %[z]\n\t"
        // slope 0 unless r != 0, r < 64000, inv != 0
        "mov %A[rem], %B[lo]\n\tcpi %A[rem], 0xFA\n\tbrcc 5f\n\t"  // r >= 64000 = 0xFA00
        "cp %A[lo], %[z]\n\tcpc %B[lo], %[z]\n\tbreq 5f\n\t"
        "cp %A[inv], %[z]\n\tcpc %B[inv], %[z]\n\tbreq 5f\n\t"
        // (rem : d) = r^2; r2_hi = d
        "mul %A[lo], %A[lo]\n\tmovw %A[rem], r0\n\t"
        "mul %B[lo], %B[lo]\n\tmovw %A[d], r0\n\t"
        "mul %A[lo], %B[lo]\n\t"
        "add %B[rem], r0\n\tadc %A[d], r1\n\tadc %B[d], %[z]\n\t"
        "add %B[rem], r0\n\tadc %A[d], r1\n\tadc %B[d], %[z]\n\t"
        // (rem : lo) = r2_hi * inv; slope = lo
        "mul %A[d], %A[inv]\n\tmovw %A[rem], r0\n\t"
        "mul %B[d], %B[inv]\n\tmovw %A[lo], r0\n\t"
        "mul %B[d], %A[inv]\n\t"
        "add %B[rem], r0\n\tadc %A[lo], r1\n\tadc %B[lo], %[z]\n\t"
        "mul %A[d], %B[inv]\n\t"
        "add %B[rem], r0\n\tadc %A[lo], r1\n\tadc %B[lo], %[z]\n\t"
        "clr __zero_reg__\n\t"
        "rjmp 6f\n"
        "5:\n\t"
        "clr %A[lo]\n\tclr %B[lo]\n"
        "6:\n\t"
        "std Z+%[o_sl], %A[lo]\n\tstd Z+%[o_sl]+1, %B[lo]\n"
        "9:"
        : [rem] "=&d"(rem), [lo] "=&r"(lo), [d] "+r"(d), [z] "=&r"(z), [inv] "=&r"(inv), "+z"(self)
        : [o_k] "I"(offsetof(OdometryQ, cfg_) + offsetof(OdometryConfigQ, wheel_rate_q11)),
          [o_inv] "I"(offsetof(OdometryQ, cfg_) + offsetof(OdometryConfigQ, inv_rate_q32)),
          [o_rpc] "I"(kOffRpc), [o_rd] "I"(kOffDiv - kOffRpc),
          [o_rq] "I"(offsetof(OdometryQ, rate_q10_) - kOffRpc), [o_sl] "I"(kOffSlope - kOffRpc)
        : "memory");
    (void)rem; (void)lo; (void)d; (void)inv;
    if (z != 0) self->set_dt_wide(self->div_.dt_us);  // dt <= 13.5 ms (self = this here)
    return;
  }
#endif
  set_dt_wide(dt_us);
}

void OdometryQ::set_dt_wide(uint32_t dt_us) {
  // the formulas of the configuration's rate_for() in fx:: arithmetic (restoring divisions, MUL
  // products), each field stored as it is formed (a RateQ built first kept 10 more registers live);
  // dt >= 13.5 ms: the rate fits 16 bits in Q10 (0 = use the 32-bit path)
  div_.dt_us = dt_us;
  div_.per_count_q11 = static_cast<int32_t>(fx::div_u32(static_cast<uint32_t>(cfg_.wheel_rate_q11), dt_us));
  div_.div_q10 = rate_q10_ = detail::rate_q10(div_.per_count_q11);
  div_.slope_q12 = detail::rate_slope<FxRateOps>(div_.div_q10, cfg_.inv_rate_q32);
}

void OdometryQ::integrate_pending() const {
  for (uint8_t i = 0; i < n_pending_; ++i) integrate_arc(pend_r_[i], pend_l_[i]);
  n_pending_ = 0;
}

// One sample's exact arc (see the header): increments dn_r, dn_l, |dn| <= kMaxStepCounts.
void OdometryQ::integrate_arc(int16_t dn_r, int16_t dn_l) const {
  // Heading: dphi = (dn_r - dn_l) * K, K = r/(2b) 2pi/ppr as binary angle + 16-bit fraction.
  // |nd| <= 32766 fits int16; the binary-angle part wraps modulo 2pi exactly (uint32
  // arithmetic), so it is formed from two 16x16 products: K = K_hi 2^16 + K_lo.
  const int16_t nd = static_cast<int16_t>(dn_r - dn_l);  // |nd| <= 32766
  const int32_t acc = static_cast<int32_t>(phi_frac_) + fx::mul_us(cfg_.dphi_per_count_frac, nd);
  phi_frac_ = static_cast<uint16_t>(acc & 0xFFFF);
  const uint16_t k_hi = static_cast<uint16_t>(cfg_.dphi_per_count_b32 >> 16);
  const uint16_t k_lo = static_cast<uint16_t>(cfg_.dphi_per_count_b32 & 0xFFFF);
  const uint32_t dphi = (static_cast<uint32_t>(fx::mul_us(k_hi, nd)) << 16) +
                        static_cast<uint32_t>(fx::mul_us(k_lo, nd)) + static_cast<uint32_t>(fx::asr<16>(acc));

  // Arc length of o, Q28 metres (|ds| <= 2.03 m for the clamped increments).
  const int16_t n_sum = static_cast<int16_t>(dn_r + dn_l);
  const int32_t ds_q28 = fx::mul32x16<16>(cfg_.ds_per_count_q44, n_sum);

  // sinc(dphi/2) = 1 - a^2/6, a = dphi/2 in rad (Q15), |a| clamped to 1 rad. Truncation error
  // a^4/120: <= 5.5e-6 for |a| <= 0.16 (a full-speed spin in 25 ms), 8e-3 at the clamp.
  int16_t t = static_cast<int16_t>(fx::asr<16>(static_cast<int32_t>(dphi)));  // 2pi/65536 units of dphi
  if (t > 20860) t = 20860;
  if (t < -20860) t = -20860;
  const int16_t a_q15 = static_cast<int16_t>(fx::mul16<14>(t, 25736));  // t * pi/2 -> Q15 rad
  const int16_t a2 = static_cast<int16_t>(fx::mul16<15>(a_q15, a_q15));
  // chord = ds sinc(a) (1 + 2^-15): the factor makes the table's cos(0) = 32767 act as exactly
  // 1.0 in the products below; (1 - o)(1 + 2^-15) = 1 - (o - 2^-15) up to o 2^-15 < 1e-7.
  const int16_t oms_q15 = static_cast<int16_t>(fx::mul16<15>(a2, 5461) - 1);
  const int32_t chord_q28 = ds_q28 - fx::mul32x16<15>(ds_q28, oms_q15);

  // Position increments in Q28; the 8 bits below Q20 are carried in x_frac_/y_frac_ so that
  // rounding does not accumulate (a constant increment would otherwise bias the position by
  // up to 0.5 LSB of Q20 per step: 2 mm over 4,000 steps).
  const uint32_t mid = pose_.phi_b32 + static_cast<uint32_t>(static_cast<int32_t>(dphi) >> 1);
  const int32_t dx_q28 = fx::mul32x16<15>(chord_q28, fx::cos_q15(mid));
  const int32_t dy_q28 = fx::mul32x16<15>(chord_q28, fx::sin_q15(mid));
  const int16_t sx = static_cast<int16_t>(x_frac_ + (dx_q28 & 0xFF));
  const int16_t sy = static_cast<int16_t>(y_frac_ + (dy_q28 & 0xFF));
  x_frac_ = static_cast<uint8_t>(sx & 0xFF);
  y_frac_ = static_cast<uint8_t>(sy & 0xFF);
  pose_.x_q20 = fx::add_sat32(pose_.x_q20, (dx_q28 >> 8) + (sx >> 8));
  pose_.y_q20 = fx::add_sat32(pose_.y_q20, (dy_q28 >> 8) + (sy >> 8));
  pose_.phi_b32 += dphi;
}

}  // namespace ctl
