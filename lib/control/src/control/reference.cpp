#include <control/reference.h>

#include <math.h>

namespace ctl {

namespace {
constexpr int16_t kInvBetaQ15 = static_cast<int16_t>(fx::q_const(1.0 / kEightBeta, 15));  // 13626
/// floor(p / 2^S) mod 2^32 of a 64-bit product for S = 16..31 (avr-gcc 5.4 shifts an int64 bit
/// by bit in __lshrdi3): bits 16..47 from the words, shifted S - 16 bits, with the bits above.
template <uint8_t S>
inline uint32_t bits64(const fx::U32x2& p) {
  const uint32_t mid = (p.hi << 16) | (p.lo >> 16);
  return S == 16 ? mid : (mid >> ((S - 16) & 31)) | (p.hi >> 16 << ((48 - S) & 31));
}

/// floor(a b / 2^16) mod 2^32 for 0 <= a < 2^31 and any int32 b, exactly (= the low word of
/// the int64 product shifted right by 16): from the unsigned product of a and b's 32 bits, less
/// 2^32 a when b < 0 (which changes only bits 32 and up: a 2^16 in the result).
inline uint32_t mul_mid32(int32_t a, int32_t b) {
  const uint32_t m = bits64<16>(fx::mul_u32x32(static_cast<uint32_t>(a), static_cast<uint32_t>(b)));
  return b < 0 ? m - (static_cast<uint32_t>(a) << 16) : m;
}

/// 2 c f1 - f0 in Q15 (one step of the Chebyshev recurrence), saturated.
inline int16_t cheb(int16_t c, int16_t f1, int16_t f0) { return fx::sat16(fx::mul16<14>(c, f1) - f0); }

// x and y series coefficients over beta |R| (reference.h).
constexpr float kEx[4] = {static_cast<float>(kEightJ(2)), static_cast<float>(kEightJ(4) / 2),
                          static_cast<float>(kEightJ(6) / 3), static_cast<float>(kEightJ(8) / 4)};
constexpr float kEy[5] = {static_cast<float>(2 * kEightJ(1)), static_cast<float>(2 * kEightJ(3) / 3),
                          static_cast<float>(2 * kEightJ(5) / 5), static_cast<float>(2 * kEightJ(7) / 7),
                          static_cast<float>(2 * kEightJ(9) / 9)};
}  // namespace

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
  if (sp.kind == PathKind::kFigureEight) {
    // phi = beta sin(tau), tau = 2 pi u / L, L = 2 pi beta |R|; positions by the Jacobi-Anger
    // series (reference.h). sin(n tau), cos(n tau) by the Chebyshev recurrence from sin, cos tau.
    const float rabs = fabsf(sp.radius_m);
    const float sgn = sp.radius_m > 0.0f ? 1.0f : -1.0f;
    const float beta = static_cast<float>(kEightBeta);
    const float period = 6.28318530717959f * beta * rabs;
    const float u = s - period * floorf(s / period);
    const float tau = 6.28318530717959f * u / period;
    const float s1 = sinf(tau), c1 = cosf(tau);
    float sn[10], cn[10];  // sin(n tau), cos(n tau), n = 0..9
    sn[0] = 0.0f;
    cn[0] = 1.0f;
    sn[1] = s1;
    cn[1] = c1;
    for (int n = 2; n < 10; ++n) {
      sn[n] = 2.0f * c1 * sn[n - 1] - sn[n - 2];
      cn[n] = 2.0f * c1 * cn[n - 1] - cn[n - 2];
    }
    float x = 0.0f, y = 0.0f;
    for (int k = 1; k <= 4; ++k) x += kEx[k - 1] * sn[2 * k];
    for (int k = 0; k <= 4; ++k) y += kEy[k] * (1.0f - cn[2 * k + 1]);
    const float br = beta * rabs;
    o.x_m = br * x;
    o.y_m = sgn * br * y;
    o.phi_rad = sgn * beta * s1;  // |phi| <= beta < pi: already in [-pi, pi)
    const float vk = v / sp.radius_m;  // v / R, signed
    o.omega_rad_s = vk * c1;
    // d omega/dt = dv kappa + v^2 dkappa/du, kappa = cos(tau)/R, dkappa/du = -sin(tau)/(beta |R| R)
    o.domega_rad_s2 = dv / sp.radius_m * c1 - vk * (v / rabs) / beta * s1;
    return o;
  }
  const float rad = sp.radius_m;  // signed: > 0 turns left
  const float u = s;
  const float phi = u / rad;
  o.x_m = rad * sinf(phi);
  o.y_m = rad * (1.0f - cosf(phi));
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
  // t in Q16 s: t_ms * 65.536 = t_ms * 65 + floor(t_ms * 549 / 1024) (error 1e-6 relative), from
  // the words th, tl of t_ms < 2^25 in 16x16 products: t_ms * 549 / 1024 = th 549 2^6 +
  // tl 549 / 1024 (t_ms * 549 in 32 bits would wrap beyond 2.17 h).
  const uint16_t th = static_cast<uint16_t>(t_ms >> 16), tl = static_cast<uint16_t>(t_ms);
  const int32_t t_q16 = static_cast<int32_t>((fx::mul_uu(th, 65) << 16) + fx::mul_uu(th, 549U * 64U) + fx::mul_uu(tl, 65) +
                                             static_cast<uint32_t>(fx::asr<10>(static_cast<int32_t>(fx::mul_uu(tl, 549)))));
  // The profile's products are exact 64-bit products of operands >= 0 (mul_u32x32).
  int32_t s_q20, v_q24, dv_q24;
  if (t_q16 < sp.t_ramp_q16) {
    // v = accel t (Q24; in the ramp below cruise, < 2^27), s = v t / 2 (Q20)
    v_q24 = static_cast<int32_t>(bits64<16>(fx::mul_u32x32(static_cast<uint32_t>(sp.accel_q24), static_cast<uint32_t>(t_q16))));
    s_q20 = static_cast<int32_t>(bits64<21>(fx::mul_u32x32(static_cast<uint32_t>(v_q24), static_cast<uint32_t>(t_q16))));
    dv_q24 = sp.accel_q24;
  } else {
    // s = s_ramp + cruise (t - t_ramp) (>= 0), saturated at INT32_MAX
    v_q24 = sp.cruise_q28 >> 4;
    const fx::U32x2 p = fx::mul_u32x32(static_cast<uint32_t>(sp.cruise_q28), static_cast<uint32_t>(t_q16 - sp.t_ramp_q16));
    const uint32_t ds = bits64<24>(p);
    s_q20 = (p.hi >> 24) != 0 || ds > static_cast<uint32_t>(INT32_MAX - sp.s_ramp_q20) ? INT32_MAX
                                                                                     : sp.s_ramp_q20 + static_cast<int32_t>(ds);
    dv_q24 = 0;
  }
  o.v_q12 = fx::sat16(fx::rshift_round<12>(v_q24));
  o.dv_q12 = fx::sat16(fx::rshift_round<12>(dv_q24));
  if (sp.kind == static_cast<uint8_t>(PathKind::kLine)) {
    o.x_q20 = s_q20;
    return o;
  }
  if (sp.kind == static_cast<uint8_t>(PathKind::kFigureEight)) {
    // tau = 2 pi s / L as a binary angle (wraps modulo 2 pi by construction, no division).
    const uint32_t tau = mul_mid32(s_q20, sp.tau_b32_per_q20);
    const int16_t s1 = fx::sin_q15(tau), c1 = fx::cos_q15(tau);
    // Harmonics by the double-angle formulas and the Chebyshev recurrence in steps of 2 tau,
    // f((n+2) tau) = 2 cos(2 tau) f(n tau) - f((n-2) tau): 9 products instead of 8 table reads.
    const int16_t s2 = fx::sat16(fx::mul16<14>(s1, c1));                    // sin 2tau
    const int16_t c2 = fx::sat16(32768L - fx::mul16<14>(s1, s1));           // cos 2tau
    const int16_t s4 = fx::sat16(fx::mul16<14>(c2, s2));
    const int16_t s6 = cheb(c2, s4, s2), s8 = cheb(c2, s6, s4);
    const int16_t c3 = cheb(c2, c1, c1);                                    // cos(-tau) = cos tau
    const int16_t c5 = cheb(c2, c3, c1), c7 = cheb(c2, c5, c3), c9 = cheb(c2, c7, c5);
    // Coefficients pre-scaled by 32768/32767 (reference.h): plain rounded (c f) >> 15 products.
    o.x_q20 = fx::mul32x16<15>(sp.cx_q20[0], s2) + fx::mul32x16<15>(sp.cx_q20[1], s4) +
              fx::mul32x16<15>(sp.cx_q20[2], s6) + fx::mul32x16<15>(sp.cx_q20[3], s8);
    // |x| <= 1.05 |R|, 0 <= y/R <= 5.7 (<= 570 m): no overflow in Q20
    o.y_q20 = sp.cy_sum_q20 - fx::mul32x16<15>(sp.cy_q20[0], c1) - fx::mul32x16<15>(sp.cy_q20[1], c3) -
              fx::mul32x16<15>(sp.cy_q20[2], c5) - fx::mul32x16<15>(sp.cy_q20[3], c7) -
              fx::mul32x16<15>(sp.cy_q20[4], c9);
    o.phi_b32 = static_cast<uint32_t>(fx::mul32x16<15>(sp.beta_b32, s1));
    // omega = (v/R) cos tau; d omega/dt = (dv/R) cos tau - (v/R)(v/|R|) sin(tau) / beta
    const int16_t vk = fx::sat16(fx::mul16<13>(o.v_q12, sp.curv_q12));                       // Q11
    const int16_t dvk = fx::sat16(fx::mul16<13>(o.dv_q12, sp.curv_q12));                     // Q11
    const int16_t vk_abs = vk < 0 ? static_cast<int16_t>(vk == INT16_MIN ? INT16_MAX : -vk) : vk;
    const int16_t vv = fx::sat16(fx::mul16<11>(vk, vk_abs));                                 // Q11
    const int16_t s_over_beta = static_cast<int16_t>(fx::mul16<15>(s1, kInvBetaQ15));        // Q15
    o.omega_q11 = fx::sat16(fx::mul16<15>(vk, c1));
    o.domega_q11 = fx::sub_sat16(fx::sat16(fx::mul16<15>(dvk, c1)), fx::sat16(fx::mul16<15>(vv, s_over_beta)));
    return o;
  }
  // phi = s / R as a binary angle (wraps modulo 2 pi by construction).
  const uint32_t phi = mul_mid32(s_q20, sp.curv_b32_per_q20);
  const int32_t rad_q20 = sp.radius_q20;
  o.phi_b32 = phi;
  o.x_q20 = fx::mul_trig<15>(rad_q20, fx::sin_q15(phi));
  o.y_q20 = rad_q20 - fx::mul_trig<15>(rad_q20, fx::cos_q15(phi));
  o.omega_q11 = fx::sat16(fx::mul16<13>(o.v_q12, sp.curv_q12));
  o.domega_q11 = fx::sat16(fx::mul16<13>(o.dv_q12, sp.curv_q12));
  return o;
}

}  // namespace ctl
