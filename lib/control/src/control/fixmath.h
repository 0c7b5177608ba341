// Fixed-point helpers for the control path: saturating conversions, narrow multiplies, constant
// shifts, divisions, and sine/cosine of a 32-bit binary angle by table with linear interpolation.
//
// Notation: a `qN` value stores round(x * 2^N). Angles on the fixed path are binary angles
// (`_b32`): uint32_t where 2^32 is one full turn, so wrap-around is free and the difference of
// two angles, cast to int32_t, is the signed difference in [-pi, pi).
//
// Every function here is integer-only; the `constexpr` helpers that take a `double` are meant
// for compile-time constants (on the AVR `double` is a 32-bit float; when they are evaluated
// in a constant expression no float code is emitted).
//
// Layout: this header states what every operation computes and holds its portable C
// implementation (namespace ctl::fx::generic, the reference). <control/avr/fixmath_avr.h> holds
// the AVR implementations (ctl::fx::avr: hardware MUL, the overflow flag, byte moves, inline
// assembly), which give the same results bit for bit in fewer cycles. The block "Selection"
// below is the one place that picks one of them for ctl::fx; the operations built on top of
// the selected ones follow it and are shared. Both implementations are compiled on the AVR, so
// a test there can compare them (bench/control_avr: the arithmetic self-test).
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

#define CTL_INLINE inline __attribute__((always_inline))


// ---- Shared building blocks (one implementation; the AVR header uses them too) ------------

/// floor((a - b) / 2) for int16 a, b, computed in 16 bits (always fits int16).
static CTL_INLINE int16_t half_diff16(int16_t a, int16_t b) {
  return static_cast<int16_t>((a >> 1) - (b >> 1) - ((b & ~a) & 1));
}

/// The high word of an int32 (x >> 16, floor), by a register move on the AVR.
static CTL_INLINE int16_t hi16(int32_t x) { return static_cast<int16_t>(static_cast<uint32_t>(x) >> 16); }

/// The range of div17(): d < 2^15 and n / 2^17 < d (a quotient of at most 17 bits; the control
/// loop's sample of 13.5 to 32.7 ms in microseconds is inside).
static CTL_INLINE bool div17_ok(uint32_t n, uint32_t d) {
  return d < 32768UL && static_cast<uint16_t>(static_cast<uint16_t>(n >> 16) >> 1) < static_cast<uint16_t>(d);
}


/// Clamp x to [-lim, lim] (lim >= 0).
static CTL_INLINE int32_t clamp32(int32_t x, int32_t lim) { return x > lim ? lim : (x < -lim ? -lim : x); }

/// Saturating int32 addition in plain C (generic::add_sat32; on the AVR used where the
/// assembly block would cost the surrounding code registers: mul32x16_halves).
static CTL_INLINE int32_t add_sat32_c(int32_t a, int32_t b) {
  const int32_t s = static_cast<int32_t>(static_cast<uint32_t>(a) + static_cast<uint32_t>(b));
  if (((a ^ s) & (b ^ s)) < 0) return a < 0 ? INT32_MIN : INT32_MAX;  // sign flip = overflow
  return s;
}

/// The exact 64-bit product of two uint32, as its two words (lo, hi): mul_u32x32().
struct U32x2 {
  uint32_t lo, hi;
};

/// The bytes of a 32-bit word (little-endian on both the AVR and x86 hosts; the byte moves
/// keep avr-gcc from emitting bit-by-bit shift loops).
union Word32 {
  uint32_t u;
  uint8_t b[4];
};

// ---- Portable implementations: the contract of every selected operation -----------------
namespace generic {

/// Saturate an int32 to int16.
static CTL_INLINE int16_t sat16(int32_t x) {
  return x > INT16_MAX ? INT16_MAX : (x < INT16_MIN ? INT16_MIN : static_cast<int16_t>(x));
}

/// Saturating int16 a + b and a - b (= sat16 of the exact int32 result).
static CTL_INLINE int16_t add_sat16(int16_t a, int16_t b) {
  const int32_t s = static_cast<int32_t>(a) + b;
  return s > INT16_MAX ? INT16_MAX : (s < INT16_MIN ? INT16_MIN : static_cast<int16_t>(s));
}
static CTL_INLINE int16_t sub_sat16(int16_t a, int16_t b) {
  const int32_t s = static_cast<int32_t>(a) - b;
  return s > INT16_MAX ? INT16_MAX : (s < INT16_MIN ? INT16_MIN : static_cast<int16_t>(s));
}

/// floor(n / d) for div17_ok(n, d).
static CTL_INLINE uint32_t div17(uint32_t n, uint16_t d) { return n / d; }

/// floor(n / d) for any 16-bit d > 0.
static CTL_INLINE uint32_t div32_16(uint32_t n, uint16_t d) { return n / d; }

/// floor(n / d) for 2^16 <= d < 2^24 (the quotient has at most 16 bits).
static CTL_INLINE uint32_t div32_24(uint32_t n, uint32_t d) { return n / d; }

/// floor(n / d), d > 0.
static inline uint32_t div_u32(uint32_t n, uint32_t d) { return n / d; }

/// Saturating int32 addition and subtraction.
static CTL_INLINE int32_t add_sat32(int32_t a, int32_t b) { return add_sat32_c(a, b); }
static CTL_INLINE int32_t sub_sat32(int32_t a, int32_t b) {
  const int32_t s = static_cast<int32_t>(static_cast<uint32_t>(a) - static_cast<uint32_t>(b));
  if (((a ^ b) & (a ^ s)) < 0) return a < 0 ? INT32_MIN : INT32_MAX;  // operands of opposite signs, sign flip
  return s;
}

/// Exact 16x16 -> 32 multiplies: signed x signed, unsigned x signed, unsigned x unsigned.
static CTL_INLINE int32_t mul_ss(int16_t a, int16_t b) {
  return static_cast<int32_t>(a) * b;
}
static CTL_INLINE int32_t mul_us(uint16_t a, int16_t b) {
  return static_cast<int32_t>(a) * b;
}
static CTL_INLINE uint32_t mul_uu(uint16_t a, uint16_t b) {
  return static_cast<uint32_t>(a) * b;
}

/// The exact 64-bit product of two uint32, as its two words (lo, hi).
static CTL_INLINE U32x2 mul_u32x32(uint32_t a, uint32_t b) {
  U32x2 r;
  const uint64_t p = static_cast<uint64_t>(a) * b;
  r.lo = static_cast<uint32_t>(p);
  r.hi = static_cast<uint32_t>(p >> 32);
  return r;
}

/// Arithmetic x >> S for a constant S (floor).
template <uint8_t S>
CTL_INLINE int32_t asr(int32_t x) {
  return x >> S;
}

/// Rounded x >> S without the overflow check, for |x| <= 2^31 - 2^(S-1) - 1 (products of two
/// 16-bit values: |x| <= 2^30).
template <uint8_t S>
CTL_INLINE int32_t rshift_round_nc(int32_t x) {
  return asr<S>(x + static_cast<int32_t>(1L << (S - 1)));
}

/// static_cast<int16_t>(rshift_round_nc<S>(x)) (the low 16 bits), S = 9..15.
template <uint8_t S>
CTL_INLINE int16_t rshift_round_nc_lo16(int32_t x) {
  return static_cast<int16_t>(static_cast<uint16_t>(static_cast<uint32_t>(x + static_cast<int32_t>(1L << (S - 1))) >> S));
}

/// sat16(rshift_round_nc<S>(x)), S = 9..15.
template <uint8_t S>
CTL_INLINE int16_t rshift_round_nc_sat16(int32_t x) {
  return sat16(asr<S>(x + static_cast<int32_t>(1L << (S - 1))));
}

/// (a * b) >> S with a 32-bit a and a 16-bit b, S in 8..16, rounded and saturated to int32:
/// sat32(floor((a b + 2^(S-1)) / 2^S)).
template <uint8_t S>
CTL_INLINE int32_t mul32x16(int32_t a, int16_t b) {
  static_assert(S >= 8 && S <= 16, "mul32x16: S in 8..16");
  const int64_t p = (static_cast<int64_t>(a) * b + (static_cast<int64_t>(1) << (S - 1))) >> S;
  return p > INT32_MAX ? INT32_MAX : (p < INT32_MIN ? INT32_MIN : static_cast<int32_t>(p));
}

/// sin of a binary angle, Q15 (|error| <= 3.5e-5: interpolation error (pi/512)^2/8 = 4.7e-6
/// plus 0.5 LSB (1.5e-5) table rounding plus 0.5 LSB interpolation rounding; measured 3.2e-5).
static CTL_INLINE int16_t sin_q15(uint32_t a_b32) {
  Word32 w;
  w.u = a_b32;
  const uint8_t quadrant = static_cast<uint8_t>(w.b[3] >> 6);
  // 22-bit position inside the quadrant: angle bits 29..8.
  Word32 p;
  p.b[0] = w.b[1];
  p.b[1] = w.b[2];
  p.b[2] = static_cast<uint8_t>(w.b[3] & 0x3F);
  p.b[3] = 0;
  if (quadrant & 1) p.u = 0x400000UL - p.u;  // mirror: sin(pi - x) = sin(x); 0..2^22
  const uint16_t mid = static_cast<uint16_t>(p.b[1] | (static_cast<uint16_t>(p.b[2]) << 8));
  const uint16_t idx = static_cast<uint16_t>(mid >> 6);  // 0..256
  const uint16_t frac16 = static_cast<uint16_t>((static_cast<uint16_t>(p.b[0] | (static_cast<uint16_t>(p.b[1]) << 8)) & 0x3FFF) << 2);
  const int16_t y0 = CTL_TABLE_READ(&detail::kSinQuarterQ15[idx]);
  int16_t y = y0;
  if (idx < 256) {
    const int16_t y1 = CTL_TABLE_READ(&detail::kSinQuarterQ15[idx + 1]);
    Word32 prod;
    prod.u = static_cast<uint32_t>(mul_us(frac16, static_cast<int16_t>(y1 - y0)) + 0x8000L);
    y = static_cast<int16_t>(y0 + static_cast<int16_t>(prod.b[2] | (static_cast<uint16_t>(prod.b[3]) << 8)));
  }
  return (quadrant & 2) ? static_cast<int16_t>(-y) : y;
}

/// cos of a binary angle, Q15.
static CTL_INLINE int16_t cos_q15(uint32_t a_b32) {
  return sin_q15(a_b32 + 0x40000000UL);
}

}  // namespace generic
}  // namespace fx
}  // namespace ctl

// ---- Selection: the one place that picks the implementation ------------------------------
#if defined(__AVR__)
#include <control/avr/fixmath_avr.h>
#define CTL_FX_IMPL avr
#else
#define CTL_FX_IMPL generic
#endif

/// Region marker for bench/control_avr/profile.sh (writes GPIOR0; empty in normal builds).
#if defined(__AVR__) && defined(CTL_PROFILE)
#define CTL_PROBE(n) __asm__ volatile("out 0x1e, %0" ::"r"(static_cast<uint8_t>(n)))
#else
#define CTL_PROBE(n) ((void)0)
#endif

namespace ctl {
namespace fx {
namespace impl = CTL_FX_IMPL;
using impl::sat16;
using impl::add_sat16;
using impl::sub_sat16;
using impl::div17;
using impl::div32_16;
using impl::div32_24;
using impl::div_u32;
using impl::add_sat32;
using impl::sub_sat32;
using impl::mul_ss;
using impl::mul_us;
using impl::mul_uu;
using impl::mul_u32x32;
using impl::asr;
using impl::rshift_round_nc;
using impl::rshift_round_nc_lo16;
using impl::rshift_round_nc_sat16;
using impl::mul32x16;
using impl::sin_q15;
using impl::cos_q15;
#undef CTL_FX_IMPL

// ---- Built on the selected operations -----------------------------------------------------

/// Rounded x >> S (S >= 1), saturating near INT32_MAX.
template <uint8_t S>
CTL_INLINE int32_t rshift_round(int32_t x) {
  const int32_t half = static_cast<int32_t>(1L << (S - 1));
  if (x > INT32_MAX - half) return INT32_MAX >> S;
  return asr<S>(x + half);
}

/// (a * b) >> S, rounded; a 16x16->32 multiply (cheap on the AVR). S in 1..30.
template <uint8_t S>
CTL_INLINE int32_t mul16(int16_t a, int16_t b) {
  return rshift_round_nc<S>(mul_ss(a, b));  // |a b| <= 2^30
}

/// The same product in plain C from two 16x16 products, a = hi 2^16 + lo (~145 cycles on the
/// AVR). Equal to mul32x16() for S = 16, and for S < 16 except that results within
/// 2^(31-S) of INT32_MIN may come out as INT32_MIN. Used only on the inner step's rare paths
/// (dt <= 13.5 ms or >= 65.5 ms): there the assembly block's six r16-r23 operands cost the
/// ordinary step ~45 cycles of register allocation (measured), even out of line.
template <uint8_t S>
CTL_INLINE int32_t mul32x16_halves(int32_t a, int16_t b) {
  const int16_t hi = static_cast<int16_t>(a >> 16);
  const uint16_t lo = static_cast<uint16_t>(a & 0xFFFF);
  const int32_t p_hi = mul_ss(hi, b);  // |p_hi| <= 2^30
  const int32_t p_lo = mul_us(lo, b);  // fits: 65535 * 32768 < 2^31
  if (S < 16) {  // p_hi * 2^(16-S) must fit int32: |p_hi| < 2^(15+S)
    const int32_t lim = static_cast<int32_t>(1L << (S < 16 ? 15 + S : 0));
    if (p_hi >= lim) return INT32_MAX;
    if (p_hi < -lim) return INT32_MIN;
  }
  // p_lo + 2^(S-1) <= 65535 * 32767 + 2^15 < 2^31: no overflow check needed.
  return add_sat32_c(p_hi * static_cast<int32_t>(1L << (16 - S)), rshift_round_nc<S>(p_lo));
}

/// (x * c) >> s for a Q15 sine/cosine c, rescaled by 32768/32767 so that c = 32767 acts as
/// exactly 1.0 (the table stores round(32767 sin)); residual scale error < 1e-9.
template <uint8_t S>
CTL_INLINE int32_t mul_trig(int32_t x, int16_t c_q15) {
  const int32_t p = mul32x16<S>(x, c_q15);
  return add_sat32(p, asr<15>(p));
}

}  // namespace fx
}  // namespace ctl

#endif  // CONTROL_FIXMATH_H
