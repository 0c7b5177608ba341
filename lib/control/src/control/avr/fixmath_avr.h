// AVR implementations of the operations of <control/fixmath.h> (avr-gcc 5.4, ATmega2560):
// the same results as ctl::fx::generic, bit for bit, in fewer cycles -- hardware MUL/MULS/MULSU,
// the overflow flag of the add/subtract, byte moves instead of bit-by-bit shift loops, unrolled
// restoring divisions, the sine table read with LPM. fixmath.h includes this header on the AVR
// and selects these functions for ctl::fx; include <control/fixmath.h>, not this header.
// Cycle counts are for the ATmega2560 (bench/control_avr measures them).
#ifndef CONTROL_AVR_FIXMATH_AVR_H
#define CONTROL_AVR_FIXMATH_AVR_H

#ifndef CONTROL_FIXMATH_H
#error "include <control/fixmath.h>: it selects this header on the AVR"
#endif

namespace ctl {
namespace fx {
namespace avr {

/// sat16: in range iff the high word is the sign extension of the low word (one 16-bit compare
/// instead of two 32-bit ones).
static CTL_INLINE int16_t sat16(int32_t x) {
  const int16_t lo = static_cast<int16_t>(x);
  const int16_t hi = static_cast<int16_t>(static_cast<uint32_t>(x) >> 16);
  if (hi != (lo < 0 ? -1 : 0)) return hi < 0 ? INT16_MIN : INT16_MAX;
  return lo;
}

/// add_sat16, sub_sat16 on the overflow flag of the 16-bit add/subtract (avr-gcc 5.4 compiles
/// the overflow builtins to compares).
static CTL_INLINE int16_t add_sat16(int16_t a, int16_t b) {
  // on overflow a and b have the same sign: 0x7FFF, plus one (0x8000) when b < 0
  __asm__(
      "add %A0, %A1\n\t"
      "adc %B0, %B1\n\t"
      "brvc 1f\n\t"
      "ldi %A0, 0xFF\n\t"
      "ldi %B0, 0x7F\n\t"
      "sbrs %B1, 7\n\t"
      "rjmp 1f\n\t"
      "subi %A0, 0xFF\n\t"
      "sbci %B0, 0xFF\n"
      "1:"
      : "+d"(a)
      : "r"(b));
  return a;
}
static CTL_INLINE int16_t sub_sat16(int16_t a, int16_t b) {
  // on overflow a and b have opposite signs: 0x7FFF, plus one (0x8000) when b >= 0
  __asm__(
      "sub %A0, %A1\n\t"
      "sbc %B0, %B1\n\t"
      "brvc 1f\n\t"
      "ldi %A0, 0xFF\n\t"
      "ldi %B0, 0x7F\n\t"
      "sbrc %B1, 7\n\t"
      "rjmp 1f\n\t"
      "subi %A0, 0xFF\n\t"
      "sbci %B0, 0xFF\n"
      "1:"
      : "+d"(a)
      : "r"(b));
  return a;
}

/// div17: a restoring division on a 16-bit remainder (17 steps, unrolled: about 145 cycles
/// instead of avr-libc's ~600 for 32 bits).
static CTL_INLINE uint32_t div17(uint32_t n, uint16_t d) {
  // Step 0: rem = n >> 16 (< 2d) gives quotient bit 16; then 16 steps shift the low word of n
  // into the remainder while the (inverted) quotient bits enter the low word from below.
  uint16_t rem = static_cast<uint16_t>(n >> 16), lo = static_cast<uint16_t>(n);
  uint8_t q16;
  __asm__(
      "cp %A[rem], %A[d]\n\t"
      "cpc %B[rem], %B[d]\n\t"
      "brcs 1f\n\t"
      "sub %A[rem], %A[d]\n\t"
      "sbc %B[rem], %B[d]\n"
      "1:\n\t"
      ".rept 16\n\t"  // unrolled (no loop counter: 3 cycles per step less)
      "rol %A[lo]\n\t"
      "rol %B[lo]\n\t"
      "rol %A[rem]\n\t"
      "rol %B[rem]\n\t"
      "cp %A[rem], %A[d]\n\t"
      "cpc %B[rem], %B[d]\n\t"
      "brcs 3f\n\t"
      "sub %A[rem], %A[d]\n\t"
      "sbc %B[rem], %B[d]\n"
      "3:\n\t"
      ".endr\n\t"
      "rol %A[lo]\n\t"
      "rol %B[lo]\n\t"
      "sbc %[q16], %[q16]\n\t"  // carry = inverted quotient bit 16
      "inc %[q16]\n\t"
      "com %A[lo]\n\t"
      "com %B[lo]\n\t"
      : [rem] "+r"(rem), [lo] "+r"(lo), [q16] "=&r"(q16)
      : [d] "r"(d));
  (void)rem;
  union { uint32_t u; uint16_t w[2]; } q;
  q.w[0] = lo;
  q.w[1] = q16;
  return q.u;
}

/// div32_16: a restoring division on a 16-bit remainder (the carry out of the shifted remainder
/// counts as a 17th bit): 16 steps when n / 2^16 < d, else 32 (about 180 or 350 cycles;
/// avr-libc's 32-bit division takes ~600).
static CTL_INLINE uint32_t div32_16(uint32_t n, uint16_t d) {
  uint16_t rem, hi = static_cast<uint16_t>(n >> 16), lo = static_cast<uint16_t>(n);
  // One step: the next bit of w enters the remainder; subtract d when the remainder (with the
  // carry out of its top) is >= d; the carry left is the inverted quotient bit, which the next
  // rol shifts into w from below.
#define CTL_DIV_STEP(w)                                                                    \
  "rol %A[" w "]\n\trol %B[" w "]\n\trol %A[rem]\n\trol %B[rem]\n\tbrcs 2f\n\t"               \
  "cp %A[rem], %A[d]\n\tcpc %B[rem], %B[d]\n\tbrcs 3f\n"                                      \
  "2:\n\tsub %A[rem], %A[d]\n\tsbc %B[rem], %B[d]\n\tclc\n"                                   \
  "3:\n\t"
  __asm__(
      "clr %A[rem]\n\tclr %B[rem]\n\t"
      "cp %A[hi], %A[d]\n\tcpc %B[hi], %B[d]\n\tbrcc 4f\n\trjmp 5f\n"  // n_hi < d: quotient < 2^16
      "4:\n\tclc\n\t"
      ".rept 16\n\t" CTL_DIV_STEP("hi") ".endr\n\t"
      "rol %A[hi]\n\trol %B[hi]\n\tcom %A[hi]\n\tcom %B[hi]\n\t"
      "rjmp 6f\n"
      "5:\n\tmovw %A[rem], %A[hi]\n\tclr %A[hi]\n\tclr %B[hi]\n"
      "6:\n\tclc\n\t"
      ".rept 16\n\t" CTL_DIV_STEP("lo") ".endr\n\t"
      "rol %A[lo]\n\trol %B[lo]\n\tcom %A[lo]\n\tcom %B[lo]"
      : [rem] "=&r"(rem), [hi] "+r"(hi), [lo] "+r"(lo)
      : [d] "r"(d));
#undef CTL_DIV_STEP
  (void)rem;
  union { uint32_t u; uint16_t w[2]; } q;
  q.w[0] = lo;
  q.w[1] = hi;
  return q.u;
}

/// div32_24: 16 restoring steps on a 24-bit remainder (the carry out of its top as a 25th bit),
/// about 230 cycles instead of avr-libc's ~600.
static CTL_INLINE uint32_t div32_24(uint32_t n, uint32_t d) {
  union { uint32_t u; uint8_t b[4]; uint16_t w[2]; } nn, dd;
  nn.u = n;
  dd.u = d;
  uint16_t lo = nn.w[0];
  uint8_t r0 = nn.b[2], r1 = nn.b[3], r2 = 0;  // remainder = n >> 16 < d
  const uint8_t d0 = dd.b[0], d1 = dd.b[1], d2 = dd.b[2];
  __asm__(
      "clc\n\t"
      ".rept 16\n\t"
      "rol %A[lo]\n\trol %B[lo]\n\trol %[r0]\n\trol %[r1]\n\trol %[r2]\n\tbrcs 2f\n\t"
      "cp %[r0], %[d0]\n\tcpc %[r1], %[d1]\n\tcpc %[r2], %[d2]\n\tbrcs 3f\n"
      "2:\n\tsub %[r0], %[d0]\n\tsbc %[r1], %[d1]\n\tsbc %[r2], %[d2]\n\tclc\n"
      "3:\n\t"
      ".endr\n\t"
      "rol %A[lo]\n\trol %B[lo]\n\tcom %A[lo]\n\tcom %B[lo]"
      : [lo] "+r"(lo), [r0] "+r"(r0), [r1] "+r"(r1), [r2] "+r"(r2)
      : [d0] "r"(d0), [d1] "r"(d1), [d2] "r"(d2));
  (void)r0; (void)r1; (void)r2;
  return lo;
}

/// div_u32: div17() in its range, div32_16() for other 16-bit d, div32_24() for 24-bit d,
/// otherwise avr-libc's n / d.
static inline uint32_t div_u32(uint32_t n, uint32_t d) {
  if (div17_ok(n, d)) return div17(n, static_cast<uint16_t>(d));
  if (d < 65536UL) return d != 0 ? div32_16(n, static_cast<uint16_t>(d)) : n / d;
  if (d < 16777216UL) return div32_24(n, d);
  return n / d;
}

/// a + b (SUB = false) or a - b (SUB = true), saturated, on the overflow flag of the 32-bit
/// add/subtract (5 cycles without overflow); on overflow the wrapped result has the wrong sign.
template <bool SUB>
CTL_INLINE int32_t addsub_sat32(int32_t a, int32_t b) {
  __asm__(
      ".if %[sub]\n\tsub %A0, %A1\n\tsbc %B0, %B1\n\tsbc %C0, %C1\n\tsbc %D0, %D1\n\t"
      ".else\n\tadd %A0, %A1\n\tadc %B0, %B1\n\tadc %C0, %C1\n\tadc %D0, %D1\n\t.endif\n\t"
      "brvc 2f\n\t"
      "brpl 1f\n\t"
      "clr %A0\n\tdec %A0\n\tmov %B0, %A0\n\tmov %C0, %A0\n\tmov %D0, %A0\n\tlsr %D0\n\trjmp 2f\n"  // INT32_MAX
      "1:\n\tclr %A0\n\tclr %B0\n\tclr %C0\n\tclr %D0\n\tsec\n\tror %D0\n"               // INT32_MIN
      "2:"
      : "+r"(a)
      : "r"(b), [sub] "M"(static_cast<uint8_t>(SUB ? 1 : 0)));
  return a;
}

static CTL_INLINE int32_t add_sat32(int32_t a, int32_t b) {
  return addsub_sat32<false>(a, b);
}
static CTL_INLINE int32_t sub_sat32(int32_t a, int32_t b) {
  return addsub_sat32<true>(a, b);
}

/// mul_ss, mul_us, mul_uu on the hardware MUL/MULS/MULSU (Atmel AVR201 scheme, ~20 cycles).
/// avr-gcc 5.4 turns (int32)hi * b and (int32)lo * b, with hi/lo taken from an int32, into full
/// 32x32 library calls (~70 cycles), and the unsigned product into a call of __umulhisi3.
static CTL_INLINE int32_t mul_ss(int16_t a, int16_t b) {
  int32_t r;
  uint8_t z;
  __asm__(
      "clr %[z]\n\t"
      "muls %B[a], %B[b]\n\t"
      "movw %C[r], r0\n\t"
      "mul %A[a], %A[b]\n\t"
      "movw %A[r], r0\n\t"
      "mulsu %B[a], %A[b]\n\t"
      "sbc %D[r], %[z]\n\t"
      "add %B[r], r0\n\t"
      "adc %C[r], r1\n\t"
      "adc %D[r], %[z]\n\t"
      "mulsu %B[b], %A[a]\n\t"
      "sbc %D[r], %[z]\n\t"
      "add %B[r], r0\n\t"
      "adc %C[r], r1\n\t"
      "adc %D[r], %[z]\n\t"
      "clr r1\n\t"
      : [r] "=&r"(r), [z] "=&r"(z)
      : [a] "a"(a), [b] "a"(b));
  return r;
}

static CTL_INLINE int32_t mul_us(uint16_t a, int16_t b) {
  int32_t r;
  uint8_t z;
  __asm__(
      "clr %[z]\n\t"
      "mulsu %B[b], %B[a]\n\t"
      "movw %C[r], r0\n\t"
      "mul %A[a], %A[b]\n\t"
      "movw %A[r], r0\n\t"
      "mul %B[a], %A[b]\n\t"
      "add %B[r], r0\n\t"
      "adc %C[r], r1\n\t"
      "adc %D[r], %[z]\n\t"
      "mulsu %B[b], %A[a]\n\t"
      "sbc %D[r], %[z]\n\t"
      "add %B[r], r0\n\t"
      "adc %C[r], r1\n\t"
      "adc %D[r], %[z]\n\t"
      "clr r1\n\t"
      : [r] "=&r"(r), [z] "=&r"(z)
      : [a] "a"(a), [b] "a"(b));
  return r;
}

static CTL_INLINE uint32_t mul_uu(uint16_t a, uint16_t b) {
  uint32_t r;
  uint8_t z;
  __asm__(
      "clr %[z]\n\t"
      "mul %B[a], %B[b]\n\t"
      "movw %C[r], r0\n\t"
      "mul %A[a], %A[b]\n\t"
      "movw %A[r], r0\n\t"
      "mul %B[a], %A[b]\n\t"
      "add %B[r], r0\n\t"
      "adc %C[r], r1\n\t"
      "adc %D[r], %[z]\n\t"
      "mul %A[a], %B[b]\n\t"
      "add %B[r], r0\n\t"
      "adc %C[r], r1\n\t"
      "adc %D[r], %[z]\n\t"
      "clr r1\n\t"
      : [r] "=&r"(r), [z] "=&r"(z)
      : [a] "r"(a), [b] "r"(b));
  return r;
}

/// mul_u32x32: one inline-assembly block of 16 MULs (~100 cycles; the int64 expression costs
/// ~200 in __mulsidi3 / __umulsidi3_helper / __umulhisi3).
static CTL_INLINE U32x2 mul_u32x32(uint32_t a, uint32_t b) {
  U32x2 r;
  uint8_t z;
  // The four products a_i b_i fill the eight bytes; the twelve a_i b_j (i != j), in pairs of
  // the same position, are added with their carries up to the top byte (the tails T*).
#define CTL_T7 "adc %D[hi], %[z]\n\t"
#define CTL_T6 "adc %C[hi], %[z]\n\t" CTL_T7
#define CTL_T5 "adc %B[hi], %[z]\n\t" CTL_T6
#define CTL_T4 "adc %A[hi], %[z]\n\t" CTL_T5
#define CTL_T3 "adc %D[lo], %[z]\n\t" CTL_T4
#define CTL_MUL2(i, j, p, q, tail)                                                        \
  "mul %" i "[a], %" j "[b]\n\tadd " p ", r0\n\tadc " q ", r1\n\t" tail                \
  "mul %" j "[a], %" i "[b]\n\tadd " p ", r0\n\tadc " q ", r1\n\t" tail
  __asm__(
      "clr %[z]\n\t"
      "mul %A[a], %A[b]\n\tmovw %A[lo], r0\n\tmul %B[a], %B[b]\n\tmovw %C[lo], r0\n\t"
      "mul %C[a], %C[b]\n\tmovw %A[hi], r0\n\tmul %D[a], %D[b]\n\tmovw %C[hi], r0\n\t"
      CTL_MUL2("A", "B", "%B[lo]", "%C[lo]", CTL_T3) CTL_MUL2("A", "C", "%C[lo]", "%D[lo]", CTL_T4)
      CTL_MUL2("A", "D", "%D[lo]", "%A[hi]", CTL_T5) CTL_MUL2("B", "C", "%D[lo]", "%A[hi]", CTL_T5)
      CTL_MUL2("B", "D", "%A[hi]", "%B[hi]", CTL_T6) CTL_MUL2("C", "D", "%B[hi]", "%C[hi]", CTL_T7)
      "clr r1"
      : [lo] "=&r"(r.lo), [hi] "=&r"(r.hi), [z] "=&r"(z)
      : [a] "r"(a), [b] "r"(b));
#undef CTL_MUL2
#undef CTL_T3
#undef CTL_T4
#undef CTL_T5
#undef CTL_T6
#undef CTL_T7
  return r;
}

/// One-bit 32-bit shifts, unrolled by Sh<N> (avr-gcc emits a counted loop, ~6 cycles per bit,
/// for a constant 32-bit shift of more than one bit; unrolled: 4 cycles per bit).
static CTL_INLINE int32_t asr1(int32_t x) {
  __asm__("asr %D0\n\tror %C0\n\tror %B0\n\tror %A0" : "+r"(x));
  return x;
}
static CTL_INLINE int32_t lsl1(int32_t x) {
  __asm__("lsl %A0\n\trol %B0\n\trol %C0\n\trol %D0" : "+r"(x));
  return x;
}
template <uint8_t N>
struct Sh {
  static CTL_INLINE int32_t r(int32_t x) { return Sh<N - 1>::r(asr1(x)); }
  static CTL_INLINE int32_t l(int32_t x) { return Sh<N - 1>::l(lsl1(x)); }
};
template <>
struct Sh<0> {
  static CTL_INLINE int32_t r(int32_t x) { return x; }
  static CTL_INLINE int32_t l(int32_t x) { return x; }
};
/// x >> (16 - K), K = 1..3 (S = 13..15): bytes 1..3 of x and a sign byte shifted left K times, and the
/// upper three of these four bytes taken (avr-gcc shifts the low word right bit by bit).
template <uint8_t K>
CTL_INLINE int32_t asr_13_15(int32_t x) {
  union { int32_t i; uint8_t b[4]; } u, v;
  u.i = x;
  uint8_t b1 = u.b[1], b2 = u.b[2], b3 = u.b[3];
  uint8_t e = (b3 & 0x80) ? 0xFF : 0;
  // K = 1..3 one-bit steps, written out (avr-gcc -Os keeps a counted loop otherwise)
  __asm__("lsl %0\n\trol %1\n\trol %2\n\trol %3" : "+r"(b1), "+r"(b2), "+r"(b3), "+r"(e));
  if (K >= 2) __asm__("lsl %0\n\trol %1\n\trol %2\n\trol %3" : "+r"(b1), "+r"(b2), "+r"(b3), "+r"(e));
  if (K >= 3) __asm__("lsl %0\n\trol %1\n\trol %2\n\trol %3" : "+r"(b1), "+r"(b2), "+r"(b3), "+r"(e));
  v.b[0] = b2; v.b[1] = b3; v.b[2] = e;
  v.b[3] = (e & 0x80) ? 0xFF : 0;
  return v.i;
}
/// x >> 8 by byte moves (sign-extended).
static CTL_INLINE int32_t asr8(int32_t x) {
  union { int32_t i; uint8_t b[4]; } u, v;
  u.i = x;
  v.b[0] = u.b[1]; v.b[1] = u.b[2]; v.b[2] = u.b[3];
  v.b[3] = (u.b[3] & 0x80) ? 0xFF : 0;
  return v.i;
}

/// asr: whole bytes are moved and the remaining bits shifted one at a time, unrolled (at most 4
/// one-bit steps: S = 5..7 and 13..15 shift the next-higher byte/word left instead).
template <uint8_t S>
CTL_INLINE int32_t asr(int32_t x) {
  if (S == 0) return x;
  if (S <= 4) return Sh<(S <= 4 ? S : 0)>::r(x);
  if (S <= 7) {  // (x >> 8) << (8 - S) | (low byte >> S)
    const uint8_t lo = static_cast<uint8_t>(static_cast<uint8_t>(x) >> (S <= 7 ? S : 0));
    return Sh<(S >= 5 && S <= 7 ? 8 - S : 0)>::l(asr8(x)) | lo;
  }
  if (S <= 12) return Sh<(S >= 8 && S <= 12 ? S - 8 : 0)>::r(asr8(x));
  if (S <= 15) return asr_13_15<(S >= 13 && S <= 15 ? 16 - S : 1)>(x);
  return static_cast<int32_t>(static_cast<int16_t>(x >> 16) >> (S >= 16 ? S - 16 : 0));
}

/// floor((x + 2^(S-1)) / 2^S) for S = 7..15, in one inline-assembly block on the bytes of x
/// (avr-gcc 5.4 otherwise moves the 32-bit value between register quadruples several times).
/// Exact whenever x + 2^(S-1) does not overflow (S = 7, 8: for every x).
///   S = 7, 8: floor(x / 2^S) + bit S-1 of x (the rounding bit, added by carry after the byte move)
///   S = 9..13: 2^(S-1) added to bytes 1..3, bytes 1..3 shifted right S-8 bits, moved down
///   S = 14, 15: 2^(S-1) added, x (plus a sign byte) shifted left 16-S bits, bytes 2..4 taken
template <uint8_t S>
CTL_INLINE int32_t rs_round(int32_t x) {
  uint8_t t;
  if (S == 7) {
    __asm__(
        "lsl %A0\n\trol %B0\n\trol %C0\n\trol %D0\n\tsbc %[t], %[t]\n\t"
        "lsl %A0\n\tmov %A0, %B0\n\tmov %B0, %C0\n\tmov %C0, %D0\n\tmov %D0, %[t]\n\t"
        "adc %A0, __zero_reg__\n\tadc %B0, __zero_reg__\n\tadc %C0, __zero_reg__\n\tadc %D0, __zero_reg__"
        : "+r"(x), [t] "=&r"(t));
  } else if (S == 8) {
    __asm__(
        "mov %[t], %D0\n\tlsl %[t]\n\tsbc %[t], %[t]\n\t"
        "lsl %A0\n\tmov %A0, %B0\n\tmov %B0, %C0\n\tmov %C0, %D0\n\tmov %D0, %[t]\n\t"
        "adc %A0, __zero_reg__\n\tadc %B0, __zero_reg__\n\tadc %C0, __zero_reg__\n\tadc %D0, __zero_reg__"
        : "+r"(x), [t] "=&r"(t));
  } else if (S >= 9 && S <= 13) {
    __asm__(
        "ldi %[t], %[h]\n\tadd %B0, %[t]\n\tadc %C0, __zero_reg__\n\tadc %D0, __zero_reg__\n\t"
        ".rept %[k]\n\tasr %D0\n\tror %C0\n\tror %B0\n\t.endr\n\t"
        "mov %A0, %B0\n\tmov %B0, %C0\n\tmov %C0, %D0\n\tlsl %D0\n\tsbc %D0, %D0"
        : "+r"(x), [t] "=&d"(t)
        : [h] "M"(static_cast<int>(1u << ((S >= 9 && S <= 13 ? S : 9) - 9))),
          [k] "M"(static_cast<int>(S - 8)));
  } else if (S == 14 || S == 15) {
    __asm__(
        "ldi %[t], %[h]\n\tadd %B0, %[t]\n\tadc %C0, __zero_reg__\n\tadc %D0, __zero_reg__\n\t"
        "mov %[t], %D0\n\tlsl %[t]\n\tsbc %[t], %[t]\n\t"
        ".rept %[k]\n\tlsl %A0\n\trol %B0\n\trol %C0\n\trol %D0\n\trol %[t]\n\t.endr\n\t"
        "mov %A0, %C0\n\tmov %B0, %D0\n\tmov %C0, %[t]\n\tmov %D0, %[t]\n\tlsl %D0\n\tsbc %D0, %D0"
        : "+r"(x), [t] "=&d"(t)
        : [h] "M"(static_cast<int>(1u << ((S == 14 || S == 15 ? S : 9) - 9))),
          [k] "M"(static_cast<int>(16 - S)));
  }
  return x;
}
/// rs_round<S>(x) (S = 9..15) truncated to 16 bits (SAT = false) or saturated to int16
/// (SAT = true), in one block; the result is left in the upper word of the register quadruple.
template <uint8_t S, bool SAT>
CTL_INLINE int16_t rs_round16(int32_t x) {
  uint8_t t;
  // in range iff the rounded value >> (S + 15) is 0 or -1, i.e. byte 3 >> (S - 9) is 0 or -1:
  // (byte 3 + 2^(S-9)) has no bit at or above S - 8
  if (S >= 9 && S <= 13) {
    __asm__(
        "ldi %[t], %[h]\n\tadd %B0, %[t]\n\tadc %C0, __zero_reg__\n\tadc %D0, __zero_reg__\n\t"
        ".if %[sat]\n\t"
        "mov %[t], %D0\n\tsubi %[t], %[nh]\n\tandi %[t], %[m]\n\tbreq 1f\n\t"
        "mov %C0, %D0\n\tlsl %C0\n\tsbc %C0, %C0\n\tldi %[t], 0x7F\n\tmov %D0, %[t]\n\t"
        "sub %D0, %C0\n\tcom %C0\n\trjmp 2f\n"
        "1:\n\t"
        ".endif\n\t"
        ".rept %[k]\n\tasr %D0\n\tror %C0\n\tror %B0\n\t.endr\n\t"
        "mov %D0, %C0\n\tmov %C0, %B0\n"
        "2:"
        : "+r"(x), [t] "=&d"(t)
        : [h] "M"(static_cast<int>(1u << ((S >= 9 && S <= 13 ? S : 9) - 9))),
          [nh] "M"(static_cast<int>(256u - (1u << ((S >= 9 && S <= 13 ? S : 9) - 9)))),
          [m] "M"(static_cast<int>(256u - (1u << ((S >= 9 && S <= 13 ? S : 9) - 8)))),
          [k] "M"(static_cast<int>(S - 8)), [sat] "M"(static_cast<uint8_t>(SAT ? 1 : 0)));
  } else if (S == 14 || S == 15) {
    __asm__(
        "ldi %[t], %[h]\n\tadd %B0, %[t]\n\tadc %C0, __zero_reg__\n\tadc %D0, __zero_reg__\n\t"
        ".if %[sat]\n\t"
        "mov %[t], %D0\n\tsubi %[t], %[nh]\n\tandi %[t], %[m]\n\tbreq 1f\n\t"
        "mov %C0, %D0\n\tlsl %C0\n\tsbc %C0, %C0\n\tldi %[t], 0x7F\n\tmov %D0, %[t]\n\t"
        "sub %D0, %C0\n\tcom %C0\n\trjmp 2f\n"
        "1:\n\t"
        ".endif\n\t"
        ".rept %[k]\n\tlsl %A0\n\trol %B0\n\trol %C0\n\trol %D0\n\t.endr\n"
        "2:"
        : "+r"(x), [t] "=&d"(t)
        : [h] "M"(static_cast<int>(1u << ((S == 14 || S == 15 ? S : 9) - 9))),
          [nh] "M"(static_cast<int>(256u - (1u << ((S == 14 || S == 15 ? S : 9) - 9)))),
          [m] "M"(static_cast<int>(256u - (1u << ((S == 14 || S == 15 ? S : 9) - 8)))),
          [k] "M"(static_cast<int>(16 - S)), [sat] "M"(static_cast<uint8_t>(SAT ? 1 : 0)));
  }
  return static_cast<int16_t>(static_cast<uint32_t>(x) >> 16);
}

/// rshift_round_nc: rs_round() for S = 7..15, otherwise asr() of the sum.
template <uint8_t S>
CTL_INLINE int32_t rshift_round_nc(int32_t x) {
  if (S >= 7 && S <= 15) return rs_round<(S >= 7 && S <= 15 ? S : 7)>(x);
  return asr<S>(x + static_cast<int32_t>(1L << (S - 1)));
}

/// rshift_round_nc_lo16, rshift_round_nc_sat16 (S = 9..15): rs_round16().
template <uint8_t S>
CTL_INLINE int16_t rshift_round_nc_lo16(int32_t x) {
  return rs_round16<S, false>(x);
}
template <uint8_t S>
CTL_INLINE int16_t rshift_round_nc_sat16(int32_t x) {
  return rs_round16<S, true>(x);
}

/// sat32(floor((a b + 2^(S-1)) / 2^S)) for S = 8..16 in one block (~70 cycles; the same in C
/// from two 16x16 products, their shifts and saturation checks took ~145): the exact 48-bit
/// product P = a b from eight MUL/MULSU/MULS (each signed partial product sign-extended by
/// SBC on the carry MULSU/MULS leave, as in mul_ss), 2^(S-1) added at its byte, then bits
/// S..S+31 taken -- from byte 2 shifted left 16-S bits (S >= 13) or from byte 1 shifted right
/// S-8 bits (S <= 12) -- and checked against the bits above them (all equal to the sign).
/// P: bytes 0,1 in lo, bytes 2..5 in r.
template <uint8_t S>
CTL_INLINE int32_t mul32x16_round(int32_t a, int16_t b) {
  int32_t r;
  uint16_t lo;
  uint8_t z, t;
  __asm__(
      "clr %[z]\n\t"
      "mul %A[a], %A[b]\n\tmovw %A[lo], r0\n\t"          // a0 b0 -> bytes 0, 1
      "mul %C[a], %A[b]\n\tmovw %A[r], r0\n\t"           // a2 b0 -> bytes 2, 3
      "muls %D[a], %B[b]\n\tmovw %C[r], r0\n\t"          // a3 b1 -> bytes 4, 5 (signed)
      "mul %B[a], %A[b]\n\t"                              // a1 b0 -> bytes 1, 2
      "add %B[lo], r0\n\tadc %A[r], r1\n\tadc %B[r], %[z]\n\tadc %C[r], %[z]\n\tadc %D[r], %[z]\n\t"
      "mulsu %D[a], %A[b]\n\t"                            // a3 b0 -> bytes 3, 4 (signed)
      "sbc %D[r], %[z]\n\tadd %B[r], r0\n\tadc %C[r], r1\n\tadc %D[r], %[z]\n\t"
      "mulsu %B[b], %A[a]\n\t"                            // a0 b1 -> bytes 1, 2 (signed)
      "sbc %B[r], %[z]\n\tsbc %C[r], %[z]\n\tsbc %D[r], %[z]\n\t"
      "add %B[lo], r0\n\tadc %A[r], r1\n\tadc %B[r], %[z]\n\tadc %C[r], %[z]\n\tadc %D[r], %[z]\n\t"
      "mulsu %B[b], %B[a]\n\t"                            // a1 b1 -> bytes 2, 3 (signed)
      "sbc %C[r], %[z]\n\tsbc %D[r], %[z]\n\t"
      "add %A[r], r0\n\tadc %B[r], r1\n\tadc %C[r], %[z]\n\tadc %D[r], %[z]\n\t"
      "mulsu %B[b], %C[a]\n\t"                            // a2 b1 -> bytes 3, 4 (signed)
      "sbc %D[r], %[z]\n\tadd %B[r], r0\n\tadc %C[r], r1\n\tadc %D[r], %[z]\n\t"
      "clr r1\n\t"
      // + 2^(S-1): bit 7 of byte 0 (S = 8) or bit S-9 of byte 1
      "ldi %[t], %[h]\n\t"
      ".if %[s8]\n\tadd %A[lo], %[t]\n\tadc %B[lo], %[z]\n\t.else\n\tadd %B[lo], %[t]\n\t.endif\n\t"
      "adc %A[r], %[z]\n\tadc %B[r], %[z]\n\tadc %C[r], %[z]\n\tadc %D[r], %[z]\n\t"
      ".if %[up]\n\t"
      // S >= 13: in range iff byte 5 >> (S - 9) is 0 or -1 (bits S+31..47 equal)
      ".if %[k]\n\t"
      "mov %[t], %D[r]\n\tsubi %[t], %[nh]\n\tandi %[t], %[m]\n\tbreq 1f\n\t"
      "mov %C[r], %D[r]\n\tlsl %C[r]\n\tsbc %C[r], %C[r]\n\tldi %[t], 0x7F\n\tmov %D[r], %[t]\n\t"
      "sub %D[r], %C[r]\n\tcom %C[r]\n\tmov %B[r], %C[r]\n\tmov %A[r], %C[r]\n\trjmp 2f\n"
      "1:\n\t"
      ".rept %[k]\n\tlsl %B[lo]\n\trol %A[r]\n\trol %B[r]\n\trol %C[r]\n\trol %D[r]\n\t.endr\n"
      "2:\n\t"
      ".endif\n\t"
      ".else\n\t"
      // S <= 12: bytes 1..5 shifted right S-8 bits; in range iff byte 5 is the sign of byte 4
      ".rept %[k]\n\tasr %D[r]\n\tror %C[r]\n\tror %B[r]\n\tror %A[r]\n\tror %B[lo]\n\t.endr\n\t"
      "mov %[t], %C[r]\n\tlsl %[t]\n\tsbc %[t], %[t]\n\t"
      "cp %[t], %D[r]\n\tbreq 1f\n\t"
      "mov %C[r], %D[r]\n\tlsl %C[r]\n\tsbc %C[r], %C[r]\n\tldi %[t], 0x7F\n\tmov %D[r], %[t]\n\t"
      "sub %D[r], %C[r]\n\tcom %C[r]\n\tmov %B[r], %C[r]\n\tmov %A[r], %C[r]\n\trjmp 2f\n"
      "1:\n\t"
      "mov %D[r], %C[r]\n\tmov %C[r], %B[r]\n\tmov %B[r], %A[r]\n\tmov %A[r], %B[lo]\n"
      "2:\n\t"
      ".endif"
      : [r] "=&r"(r), [lo] "=&r"(lo), [z] "=&r"(z), [t] "=&d"(t)
      : [a] "a"(a), [b] "a"(b), [h] "M"(static_cast<int>(S == 8 ? 0x80 : (1u << ((S >= 9 && S <= 16 ? S : 9) - 9)))),
        [s8] "M"(static_cast<int>(S == 8 ? 1 : 0)), [up] "M"(static_cast<int>(S >= 13 ? 1 : 0)),
        [k] "M"(static_cast<int>(S >= 13 ? 16 - S : S - 8)),
        [nh] "M"(static_cast<int>(256u - (1u << ((S >= 13 && S <= 15 ? S : 15) - 9)))),
        [m] "M"(static_cast<int>(256u - (1u << ((S >= 13 && S <= 15 ? S : 15) - 8)))));
  (void)lo;
  return r;
}

/// mul32x16: one inline-assembly block (mul32x16_round).
template <uint8_t S>
CTL_INLINE int32_t mul32x16(int32_t a, int16_t b) {
  static_assert(S >= 8 && S <= 16, "mul32x16: S in 8..16");
  return mul32x16_round<S>(a, b);
}

/// sin_q15(a + C 2^30) (C = 0: sine, 1: cosine) in one block, ~55 cycles instead of ~145 for
/// the same C: the quadrant byte (+ C 0x40), the 22-bit position mirrored in odd quadrants,
/// shifted left 2 bits (index in the top byte, the 16-bit fraction below; a carry out is the
/// position 2^22, index 256), the table words read with LPM Z+, the fraction times their
/// difference (bytes 2, 3 of two MUL products, rounded), negated in quadrants 2 and 3. The
/// quarter-wave table increases by 1..201 per entry (test_control_blocks checks 0..255), so
/// the difference is the low bytes' difference, one unsigned byte.
template <uint8_t C>
CTL_INLINE int16_t sin_table(uint32_t a_b32) {
  int16_t y;
  uint8_t q, p0, p1, p2, d, t, z;
  const int16_t* tab = &detail::kSinQuarterQ15[0];
  __asm__(
      "mov %[p2], %D[a]\n\t"
      ".if %[c]\n\tsubi %[p2], 0xC0\n\t.endif\n\t"
      "mov %[q], %[p2]\n\tmov %[p0], %B[a]\n\tmov %[p1], %C[a]\n\tandi %[p2], 0x3F\n\t"
      "sbrs %[q], 6\n\trjmp 1f\n\t"
      "com %[p2]\n\tcom %[p1]\n\tneg %[p0]\n\tsbci %[p1], 0xFF\n\tsbci %[p2], 0xFF\n\tsubi %[p2], 0xC0\n"  // 2^22 - p
      "1:\n\t"
      "lsl %[p0]\n\trol %[p1]\n\trol %[p2]\n\tlsl %[p0]\n\trol %[p1]\n\trol %[p2]\n\t"
      "clr %[z]\n\t"
      "brcs 5f\n\t"
      "add r30, %[p2]\n\tadc r31, %[z]\n\tadd r30, %[p2]\n\tadc r31, %[z]\n\t"
      "lpm %A[y], Z+\n\tlpm %B[y], Z+\n\tlpm %[d], Z\n\tsub %[d], %A[y]\n\t"  // d = y1 - y0
      "mul %[p0], %[d]\n\tmov %[t], r1\n\t"                               // byte 1
      "mul %[p1], %[d]\n\tadd %[t], r0\n\tadc r1, %[z]\n\t"               // byte 2 in r1
      "lsl %[t]\n\tadc r1, %[z]\n\t"                                         // + 0x8000
      "add %A[y], r1\n\tadc %B[y], %[z]\n\tclr r1\n\trjmp 6f\n"
      "5:\n\t"                                                               // index 256
      "subi r30, lo8(-512)\n\tsbci r31, hi8(-512)\n\tlpm %A[y], Z+\n\tlpm %B[y], Z\n"
      "6:\n\t"
      "sbrs %[q], 7\n\trjmp 7f\n\t"
      "neg %A[y]\n\tadc %B[y], %[z]\n\tneg %B[y]\n"
      "7:"
      : [y] "=&r"(y), [q] "=&r"(q), [p0] "=&r"(p0), [p1] "=&d"(p1), [p2] "=&d"(p2), [d] "=&r"(d),
        [t] "=&r"(t), [z] "=&r"(z), "+z"(tab)
      : [a] "r"(a_b32), [c] "M"(C));
  (void)q; (void)p0; (void)p1; (void)p2; (void)d; (void)t; (void)z; (void)tab;
  return y;
}

/// sin_q15, cos_q15: sin_table(), the same arithmetic as generic::sin_q15.
static CTL_INLINE int16_t sin_q15(uint32_t a_b32) {
  return sin_table<0>(a_b32);
}
static CTL_INLINE int16_t cos_q15(uint32_t a_b32) {
  return sin_table<1>(a_b32);
}

}  // namespace avr
}  // namespace fx
}  // namespace ctl

#endif  // CONTROL_AVR_FIXMATH_AVR_H
