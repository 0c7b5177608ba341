// Fixed-point helpers for the AVR control path: saturating conversions, narrow multiplies,
// and sine/cosine of a 32-bit binary angle by table with linear interpolation.
//
// Notation: a `qN` value stores round(x * 2^N). Angles on the fixed path are binary angles
// (`_b32`): uint32_t where 2^32 is one full turn, so wrap-around is free and the difference of
// two angles, cast to int32_t, is the signed difference in [-pi, pi).
//
// Every function here is integer-only; the `constexpr` helpers that take a `double` are meant
// for compile-time constants (on the AVR `double` is a 32-bit float; when they are evaluated
// in a constant expression no float code is emitted).
#ifndef CONTROL_FIXMATH_H
#define CONTROL_FIXMATH_H

#include <stdint.h>

#include <control/sin_table.h>

namespace ctl {
namespace fx {

static const int16_t kQ15One = 32767;  ///< largest Q15 value (1.0 - 2^-15)

/// 2^n as a double, for compile-time constants (no `1L << n`: long is 32-bit on the AVR).
constexpr double pow2(int n) { return n <= 0 ? 1.0 : 2.0 * pow2(n - 1); }

/// Round-to-nearest conversion of a compile-time constant to Q`shift` (saturated to int32).
constexpr int32_t q_const(double v, int shift) {
  return (v * pow2(shift)) >= 2147483647.0
             ? INT32_MAX
             : (v * pow2(shift)) <= -2147483648.0
                   ? INT32_MIN
                   : (v >= 0.0 ? static_cast<int32_t>(v * pow2(shift) + 0.5)
                               : -static_cast<int32_t>(-v * pow2(shift) + 0.5));
}

/// Saturate an int32 to int16.
static inline int16_t sat16(int32_t x) {
  return x > INT16_MAX ? INT16_MAX : (x < INT16_MIN ? INT16_MIN : static_cast<int16_t>(x));
}

/// Clamp x to [-lim, lim] (lim >= 0).
static inline int32_t clamp32(int32_t x, int32_t lim) { return x > lim ? lim : (x < -lim ? -lim : x); }
static inline int16_t clamp16(int16_t x, int16_t lim) { return x > lim ? lim : (x < -lim ? -lim : x); }

/// Saturating int32 addition.
static inline int32_t add_sat32(int32_t a, int32_t b) {
  const int32_t s = static_cast<int32_t>(static_cast<uint32_t>(a) + static_cast<uint32_t>(b));
  if (((a ^ s) & (b ^ s)) < 0) return a < 0 ? INT32_MIN : INT32_MAX;  // sign flip = overflow
  return s;
}

/// Rounded arithmetic right shift (s >= 1).
static inline int32_t rshift_round(int32_t x, uint8_t s) {
  // x + half cannot overflow unless x is within 2^(s-1) of INT32_MAX; saturate then.
  const int32_t half = static_cast<int32_t>(1L << (s - 1));
  if (x > INT32_MAX - half) return INT32_MAX >> s;
  return (x + half) >> s;
}

/// (a * b) >> s, rounded; a 16x16->32 multiply (cheap on the AVR). s in 1..30.
static inline int32_t mul16(int16_t a, int16_t b, uint8_t s) {
  return rshift_round(static_cast<int32_t>(a) * b, s);
}

/// (a * b) >> s with a 32-bit a and a 16-bit b, s in 1..16, rounded and saturated to int32.
/// Done as two 16x16 multiplies: a = hi * 2^16 + lo.
static inline int32_t mul32x16(int32_t a, int16_t b, uint8_t s) {
  const int16_t hi = static_cast<int16_t>(a >> 16);
  const uint16_t lo = static_cast<uint16_t>(a & 0xFFFF);
  const int32_t p_hi = static_cast<int32_t>(hi) * b;       // |p_hi| <= 2^30
  const int32_t p_lo = static_cast<int32_t>(lo) * b;       // fits: 65535 * 32768 < 2^31
  const uint8_t up = static_cast<uint8_t>(16 - s);
  const int32_t lim = static_cast<int32_t>(1L << (30 - up));  // |p_hi << up| < 2^30
  if (p_hi >= lim) return INT32_MAX;
  if (p_hi < -lim) return INT32_MIN;
  return add_sat32(p_hi * static_cast<int32_t>(1L << up), rshift_round(p_lo, s));
}

/// sin of a binary angle, Q15 (|error| <= 2.1e-5 incl. rounding: interpolation error
/// (pi/512)^2/8 = 4.7e-6 plus 0.5 LSB table rounding and 0.5 LSB interpolation rounding).
static inline int16_t sin_q15(uint32_t a_b32) {
  const uint8_t quadrant = static_cast<uint8_t>(a_b32 >> 30);
  // Position inside the quadrant: 8 bits of index, 15 bits of interpolation fraction.
  uint32_t in_q = a_b32 & 0x3FFFFFFFUL;
  if (quadrant & 1) in_q = 0x40000000UL - in_q;  // mirror: sin(pi - x) = sin(x)
  const uint16_t idx = static_cast<uint16_t>(in_q >> 22);  // 0..256
  const int16_t frac = static_cast<int16_t>((in_q >> 7) & 0x7FFF);
  const int16_t y0 = CTL_TABLE_READ(&detail::kSinQuarterQ15[idx]);
  int16_t y = y0;
  if (idx < 256) {
    const int16_t y1 = CTL_TABLE_READ(&detail::kSinQuarterQ15[idx + 1]);
    y = static_cast<int16_t>(y0 + mul16(static_cast<int16_t>(y1 - y0), frac, 15));
  }
  return (quadrant & 2) ? static_cast<int16_t>(-y) : y;
}

/// cos of a binary angle, Q15.
static inline int16_t cos_q15(uint32_t a_b32) { return sin_q15(a_b32 + 0x40000000UL); }

/// (x * c) >> s for a Q15 sine/cosine c, rescaled by 32768/32767 so that c = 32767 acts as
/// exactly 1.0 (the table stores round(32767 sin)); residual scale error < 1e-9.
static inline int32_t mul_trig(int32_t x, int16_t c_q15, uint8_t s) {
  const int32_t p = mul32x16(x, c_q15, s);
  return add_sat32(p, p >> 15);
}

/// Binary angle (int32 view: [-2^31, 2^31) = [-pi, pi)) to radians in Q12 (int16, |x| <= pi).
static inline int16_t b32_to_rad_q12(int32_t a_b32) {
  // rad = a * 2pi / 2^32; Q12: a * 2pi / 2^20 = (a >> 16) * 2pi / 2^4 = (a >> 16) * 25736 >> 16
  return static_cast<int16_t>(mul16(static_cast<int16_t>(a_b32 >> 16), 25736, 16));
}

}  // namespace fx
}  // namespace ctl

#endif  // CONTROL_FIXMATH_H
