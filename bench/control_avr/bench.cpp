// AVR cycle benchmark of lib/control: one inner and one outer step, float and fixed point.
// Built like the firmware (avr-g++ 5.4, -Os, -mmcu=atmega2560, F_CPU 16 MHz) and run in simavr
// by bench/control_avr/run.sh. Timer1 runs at prescaler 1, so TCNT1 counts CPU cycles; the
// cost of reading the timer around an empty call is measured and subtracted. Every figure is
// the min / mean / max over kRuns calls with varying encoder counts on an arc reference
// (trigonometry active, both wheels moving, clamp on).
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <stdint.h>
#include <stdio.h>

#include <control/cascade.h>
#include <control/cascade_q.h>
#include <control/drive.h>
#include <control/reference.h>

#include "sequence.h"

namespace {

int uart_putchar(char c, FILE*) {
  while (!(UCSR0A & (1 << UDRE0))) {
  }
  UDR0 = static_cast<uint8_t>(c);
  return 0;
}
FILE uart_out;

using bench::kRuns;

struct Stat {
  uint32_t sum;
  uint16_t lo, hi, n;
  void reset() { sum = 0; lo = 0xFFFF; hi = 0; n = 0; }
  void add(uint16_t c) {
    sum += c;
    ++n;
    if (c < lo) lo = c;
    if (c > hi) hi = c;
  }
};

uint16_t overhead;

// Times `expr` in CPU cycles (Timer1 at clk/1); an overflow (> 65535 cycles) is reported.
#define TIME_IT(stat, expr)                              \
  do {                                                   \
    TCNT1 = 0;                                           \
    TIFR1 = (1 << TOV1);                                 \
    const uint16_t t0_ = TCNT1;                          \
    expr;                                                \
    const uint16_t t1_ = TCNT1;                          \
    if (TIFR1 & (1 << TOV1)) overflowed = true;          \
    last_cycles = static_cast<uint16_t>(t1_ - t0_ - overhead); \
    (stat).add(last_cycles);                             \
  } while (0)

// Forces v to be computed before this point (the compiler may otherwise sink the computation
// of a call's arguments, e.g. a division, between the two reads of TCNT1).
template <typename T>
inline T opaque(T v) {
  __asm__ volatile("" : "+r"(v));
  return v;
}

bool overflowed = false;
uint16_t last_cycles;
volatile int32_t sink;

// Reference saturation for the self-test (int64 arithmetic).
int32_t ref_sat32(int64_t v) { return v > INT32_MAX ? INT32_MAX : (v < INT32_MIN ? INT32_MIN : static_cast<int32_t>(v)); }

void row(const char* name, const Stat& s) {
  printf("%-44s %6u %6lu %6u %4u\n", name, s.lo, static_cast<unsigned long>(s.sum / s.n), s.hi, s.n);
}

// Configuration (built once at start-up; the float conversion is not part of the steps).
ctl::ControlConfig cfg =
    ctl::make_control_config(slip::RobotParams(), slip::MotorParams(), ctl::default_gains(), true);
ctl::ControlConfigQ cfg_q(cfg);
const ctl::ReferenceSpec spec{ctl::PathKind::kArc, 0.5f, 0.4f, 0.6f};
constexpr ctl::ReferenceSpecQ spec_q{ctl::ReferenceSpec{ctl::PathKind::kArc, 0.5f, 0.4f, 0.6f}};
constexpr ctl::ReferenceSpecQ spec8_q{bench::kEightSpec};
ctl::Controller fc(cfg);
ctl::ControllerQ qc(cfg_q);        // the firmware's sequence: reset, then dt = 25 ms +- 4 us
ctl::ControllerQ qc_const(cfg_q);  // same sequence with a constant dt (cached reciprocal)
ctl::ControllerQ qc_div(cfg_q);    // same counts, dt jumping on every call (every call divides)
ctl::ControllerQ qc8(cfg_q);       // same counts, the outer task on the figure eight
ctl::ControllerQ qcd(cfg_q);       // same counts, the outer task in drive mode
ctl::DriveReferenceQ drive_task, drive_alone;
const ctl::DriveConfigQ kDriveCfg(ctl::DriveLimits{1.0f, 4.0f}, 50000UL);
ctl::ControllerQ qc_start(cfg_q);  // the start tick (reset, outer step at t = 0, first command)

}  // namespace

namespace ctl {
// Access to OdometryQ's private rate state for the self-test: set_dt() (inline assembly on the
// AVR) must leave exactly the state set_dt_wide() (plain C) leaves, for every dt.
struct OdometryQProbe {
  static void set_dt(OdometryQ& a, uint32_t dt_us) { a.set_dt(dt_us); }
  static uint8_t check(OdometryQ& a, OdometryQ& b, uint32_t dt_us) {
    a.set_dt(dt_us);
    b.set_dt_wide(dt_us);
    return differ(a, b.div_) + (a.rate_q10_ != b.rate_q10_);
  }
  // The rate state of `a` (after a division) against a RateQ computed elsewhere.
  static uint8_t differ(const OdometryQ& a, const RateQ& r) {
    return (a.div_.dt_us != r.dt_us) + (a.div_.per_count_q11 != r.per_count_q11) + (a.div_.div_q10 != r.div_q10) +
           (a.div_.slope_q12 != r.slope_q12) + (a.rate_q10_ != r.div_q10);
  }
};
}  // namespace ctl

int main() {
  UBRR0 = 8;  // 115200 Bd at 16 MHz (irrelevant in simavr)
  UCSR0B = (1 << TXEN0);
  fdev_setup_stream(&uart_out, uart_putchar, NULL, _FDEV_SETUP_WRITE);
  stdout = &uart_out;
  TCCR1A = 0;
  TCCR1B = (1 << CS10);  // clk/1

  // Overhead of the measurement itself.
  {
    Stat s;
    s.reset();
    overhead = 0;
    for (uint8_t i = 0; i < kRuns; ++i) TIME_IT(s, sink = i);
    overhead = s.lo;
  }

  Stat in_q, in_q_const, in_q_free, out_q, ref_q, task8_q, in_f, out_f, ref_f, start_q, drive_q, taskd_q;
  drive_q.reset(); taskd_q.reset();
  in_q.reset(); in_q_const.reset(); in_q_free.reset(); out_q.reset(); ref_q.reset(); task8_q.reset(); in_f.reset();
  out_f.reset(); ref_f.reset(); start_q.reset();
  const ctl::RefSampleQ r0 = ctl::reference_at_q(spec_q, opaque(0UL));
  // As the firmware starts an experiment: reset with the encoders' counts, then inner steps
  // with dt = 25 ms +- 4 us from the first one on (the reset's nominal rate: no division).
  qc.reset(bench::enc_r_at(0), bench::enc_l_at(0), ctl::PoseQ{0, 0, 0});
  ctl::RefSampleQ rq{};
  ctl::RefSample rf;
  uint32_t check = 0;
  uint8_t limited = 0;
  for (uint8_t i = 0; i < kRuns; ++i) {
    const int32_t enc_r = opaque(bench::enc_r_at(i)), enc_l = opaque(bench::enc_l_at(i));
    const uint32_t t_ms = opaque(25UL * i);
    const uint32_t dt_us = opaque(bench::dt_us_at(i));  // not inside the timed call (it divides by 9)
    TIME_IT(in_q, qc.inner_step(enc_r, enc_l, dt_us));
    const ctl::InnerOutQ& oq = qc.inner();
    if (!(oq.clamped_r || oq.clamped_l || oq.sat_r || oq.sat_l)) in_q_free.add(last_cycles);
#ifndef CTL_PROFILE  // profile.sh: the jittered-dt controller alone
    TIME_IT(in_q_const, qc_const.inner_step(enc_r, enc_l, 25000UL));
    TIME_IT(start_q, qc_start.start(enc_r, enc_l, ctl::PoseQ{0, 0, 0}, r0));
#endif
    if (bench::outer_due(i)) qc_const.outer_step(rq);  // rq: the previous sample (untimed)
    if (bench::outer_due(i)) {
      // timed as a value consumed in place (an assignment may add a 20-byte copy loop, ~140
      // cycles, depending on the surrounding code); the sample is then formed again, untimed
      TIME_IT(ref_q, sink = ctl::reference_at_q(spec_q, t_ms).x_q20);
      rq = ctl::reference_at_q(spec_q, t_ms);
      TIME_IT(out_q, qc.outer_step(rq));
    }
    check = bench::checksum_step(check, qc, rq, i);
    TIME_IT(in_f, fc.inner_step(enc_r, enc_l, 0.025f));
    if (bench::outer_due(i)) {
      TIME_IT(ref_f, rf = ctl::reference_at(spec, 0.025f * i));
      TIME_IT(out_f, fc.outer_step(rf));
    }
    if (qc.inner().clamped_r || qc.inner().clamped_l || qc.inner().sat_r || qc.inner().sat_l) ++limited;
#ifndef CTL_PROFILE
    // The firmware's outer task on the figure eight: its reference sample and the outer step
    // (two queued arcs), timed together.
    qc8.inner_step(enc_r, enc_l, dt_us);
    if (bench::outer_due(i)) TIME_IT(task8_q, qc8.outer_step(ctl::reference_at_q(spec8_q, t_ms)));
    // Drive mode's outer task: the Drive target (mm/s, mrad/s, changing every tick so that the
    // reference ramps and turns) converted, the reference stepped, the outer step.
    qcd.inner_step(enc_r, enc_l, dt_us);
    if (bench::outer_due(i)) {
      const int16_t v_mm = opaque(static_cast<int16_t>((i * 37) % 1400 - 300));
      const int16_t w_mrad = opaque(static_cast<int16_t>((i * 53) % 6000 - 3000));
      TIME_IT(drive_q, sink = drive_alone.step(kDriveCfg, ctl::drive_v_q12(v_mm), ctl::drive_omega_q11(w_mrad)).x_q20);
      TIME_IT(taskd_q, qcd.outer_step(drive_task.step(kDriveCfg, ctl::drive_v_q12(v_mm), ctl::drive_omega_q11(w_mrad))));
    }
#endif
  }
  sink = qc.inner().pwm_r_q15 + static_cast<int32_t>(fc.inner().pwm_r * 1000.0f);

  // The step that divides (dt more than 63 us from the last divided dt): the same counts and
  // outer steps, dt jumping through 13.6-32.7 ms by 7,919 us (mod 19,100) so that every call
  // divides; then dt outside that range (the 32-bit rate below 13.5 ms, avr-libc's division
  // from 32.8 ms, the long-dt integrators from 65.5 ms), each value in turn.
  Stat in_div, in_lo, in_mid, in_long;
  in_div.reset(); in_lo.reset(); in_mid.reset(); in_long.reset();
#ifndef CTL_PROFILE
  {
    ctl::RefSampleQ r{};
    for (uint8_t i = 0; i < kRuns; ++i) {
      const int32_t enc_r = opaque(bench::enc_r_at(i)), enc_l = opaque(bench::enc_l_at(i));
      const uint32_t dt_us = opaque(13600UL + (7919UL * i) % 19100UL);
      TIME_IT(in_div, qc_div.inner_step(enc_r, enc_l, dt_us));
      if (bench::outer_due(i)) {
        r = ctl::reference_at_q(spec_q, 25UL * i);
        qc_div.outer_step(r);
      }
    }
    static const uint32_t kOut[] = {5000UL, 10000UL, 13000UL, 13500UL, 33000UL, 40000UL, 50000UL, 65000UL,
                                    70000UL, 100000UL, 300000UL};
    for (uint8_t i = 0; i < kRuns; ++i) {
      const uint8_t j = static_cast<uint8_t>(i % (sizeof kOut / sizeof kOut[0]));
      const int32_t enc_r = opaque(bench::enc_r_at(i)), enc_l = opaque(bench::enc_l_at(i));
      const uint32_t dt_us = opaque(kOut[j]);
      Stat& st = dt_us < 13542UL ? in_lo : (dt_us < 65536UL ? in_mid : in_long);
      TIME_IT(st, qc_div.inner_step(enc_r, enc_l, dt_us));
      if (bench::outer_due(i)) qc_div.outer_step(r);
    }
  }
#endif

  // The figure-eight reference over more than one lap (its own row and checksum).
  Stat ref8_q, ref8_f;
  ref8_q.reset(); ref8_f.reset();
  uint32_t check8 = 0;
#ifndef CTL_PROFILE
  for (uint8_t i = 0; i < kRuns; ++i) {
    const uint32_t t_ms = opaque(bench::eight_t_ms(i));
    const float t_s = opaque(0.001f * static_cast<float>(bench::eight_t_ms(i)));
    ctl::RefSampleQ r8{};
    ctl::RefSample f8;
    TIME_IT(ref8_q, sink = ctl::reference_at_q(spec8_q, t_ms).x_q20);  // as the arc's row
    r8 = ctl::reference_at_q(spec8_q, t_ms);
    check8 = bench::checksum_ref(check8, r8);
    TIME_IT(ref8_f, f8 = ctl::reference_at(bench::kEightSpec, t_s));
    sink = static_cast<int32_t>(f8.x_m * 1000.0f);
  }
#endif

  printf("BEGIN control_avr cycles (ATmega2560, -Os, %u calls each, overhead %u subtracted)\n",
         static_cast<unsigned>(kRuns), overhead);
  printf("%-44s %6s %6s %6s %4s\n", "step", "min", "mean", "max", "n");
  row("fixed inner_step firmware (reset, 25ms+-4us)", in_q);
  row("  ... steps not limited (integrating)", in_q_free);
  row("fixed inner_step (dt constant)", in_q_const);
  row("fixed inner_step off-schedule 13.6-32.7 ms", in_div);
  row("  dt 5-13.5 ms (32-bit rate)", in_lo);
  row("  dt 33-65 ms (16-bit divisor)", in_mid);
  row("  dt 70-300 ms (long dt)", in_long);
  row("fixed outer_step (50 ms)", out_q);
  row("fixed reference_at_q", ref_q);
  row("fixed reference_at_q, figure eight", ref8_q);
  row("fixed outer task, figure eight", task8_q);
  row("fixed drive reference step (Drive target in)", drive_q);
  row("fixed outer task, drive mode", taskd_q);
  row("fixed start (reset, outer, first command)", start_q);
  printf("fixed outer_step max + figure-eight sample max: %u\n", out_q.hi + ref8_q.hi);
  row("float inner_step (25 ms)", in_f);
  row("float outer_step (50 ms)", out_f);
  row("float reference_at", ref_f);
  row("float reference_at, figure eight", ref8_f);
  printf("state bytes: ControllerQ %u, Controller %u\n", static_cast<unsigned>(sizeof(ctl::ControllerQ)),
         static_cast<unsigned>(sizeof(ctl::Controller)));
  printf("fixed inner steps with the clamp or the duty limited: %u of %u\n", limited, static_cast<unsigned>(kRuns));
  printf("timer overflow: %s\n", overflowed ? "YES (figures invalid)" : "no");
  printf("avr fixed-point checksum %08lx %08lx %08lx %08lx\n", static_cast<unsigned long>(check),
         static_cast<unsigned long>(check8), static_cast<unsigned long>(bench::checksum_trig()),
         static_cast<unsigned long>(bench::checksum_long()));
  printf("avr config");
  uint8_t field = 0;
#define BENCH_PRINT(f) \
  if (++field % 12 == 0) printf("\navr config"); \
  printf(" %ld", static_cast<long>(cfg_q.f));
  BENCH_CFG_FIELDS(BENCH_PRINT)
  printf("\navr config");  // simavr splits long UART lines: keep them short
  field = 0;
#define BENCH_PRINT_REF(f) \
  if (++field % 12 == 0) printf("\navr config"); \
  printf(" %ld", static_cast<long>(spec_q.f));
  BENCH_REF_FIELDS(BENCH_PRINT_REF)
  printf("\navr config");
  field = 0;
#define BENCH_PRINT_REF8(f) \
  if (++field % 12 == 0) printf("\navr config"); \
  printf(" %ld", static_cast<long>(spec8_q.f));
  BENCH_REF_FIELDS(BENCH_PRINT_REF8)
  printf("\n");
  // Self-test of the AVR-only arithmetic (inline-assembly multiplies, byte-move shifts).
  uint32_t bad = 0, n = 0, x = 12345;
  for (uint16_t k = 0; k < 3000; ++k) {
    x = x * 1103515245UL + 12345UL;
    const int16_t a = static_cast<int16_t>(x >> 16), b = static_cast<int16_t>(x);
    const uint16_t ua = static_cast<uint16_t>(x >> 8);
    const int32_t w = static_cast<int32_t>(x ^ (x << 7));
    bad += ctl::fx::mul_ss(a, b) != static_cast<int32_t>(a) * static_cast<int32_t>(b);
    bad += ctl::fx::mul_us(ua, b) != static_cast<int32_t>(static_cast<uint32_t>(ua)) * static_cast<int32_t>(b);
    bad += ctl::fx::mul_uu(ua, static_cast<uint16_t>(x)) != static_cast<uint32_t>(ua) * static_cast<uint16_t>(x);
    ++n;
    // the selected (AVR) implementations against the portable ones of fixmath.h on the same
    // inputs: the clamp of sat16 over every magnitude, the sine table over the whole turn
    bad += ctl::fx::sat16(w >> (k % 32)) != ctl::fx::generic::sat16(w >> (k % 32));
    bad += ctl::fx::sin_q15(x) != ctl::fx::generic::sin_q15(x);
    bad += ctl::fx::cos_q15(x) != ctl::fx::generic::cos_q15(x);
    n += 3;
#define ASR_CHECK(S) bad += ctl::fx::asr<S>(w) != (w >> S);
    ASR_CHECK(1) ASR_CHECK(2) ASR_CHECK(3) ASR_CHECK(4) ASR_CHECK(5) ASR_CHECK(6) ASR_CHECK(7)
    ASR_CHECK(8) ASR_CHECK(9) ASR_CHECK(10) ASR_CHECK(11) ASR_CHECK(12) ASR_CHECK(13)
    ASR_CHECK(14) ASR_CHECK(15) ASR_CHECK(16) ASR_CHECK(17) ASR_CHECK(20)
    n += 20;
    // the exact 32x32 unsigned product (inline assembly), against uint64
    {
      const uint32_t ua32 = x ^ (x << 11), ub32 = (x * 2654435761UL) >> (k % 32);
      const uint64_t e = static_cast<uint64_t>(ua32) * ub32;
      const ctl::fx::U32x2 p = ctl::fx::mul_u32x32(ua32, ub32);
      bad += p.lo != static_cast<uint32_t>(e) || p.hi != static_cast<uint32_t>(e >> 32);
      ++n;
    }
    // saturating 32-bit add and subtract (inline assembly), against int64; the operands span
    // the whole range (w >> 0..3), so both saturations are exercised
    {
      const int32_t p = w >> (k & 3), q = static_cast<int32_t>(x * 2654435761UL) >> ((k >> 2) & 3);
      const int64_t s1 = static_cast<int64_t>(p) + q, s2 = static_cast<int64_t>(p) - q;
      bad += ctl::fx::add_sat32(p, q) != ref_sat32(s1);
      bad += ctl::fx::sub_sat32(p, q) != ref_sat32(s2);
      n += 2;
    }
    // saturating 16-bit add and subtract
    {
      const int32_t s1 = static_cast<int32_t>(a) + b, s2 = static_cast<int32_t>(a) - b;
      bad += ctl::fx::add_sat16(a, b) != (s1 > 32767 ? 32767 : (s1 < -32768 ? -32768 : s1));
      bad += ctl::fx::sub_sat16(a, b) != (s2 > 32767 ? 32767 : (s2 < -32768 ? -32768 : s2));
      n += 2;
    }
    // rounded shifts (inline assembly for S = 7..15), their 16-bit truncated and saturated
    // forms; |v| <= 2^30 (the precondition), magnitudes spread so that saturation is exercised
    {
      const int32_t v = static_cast<int32_t>(w) >> (2 + (k % 24));
#define RS_REF(S) static_cast<int32_t>((static_cast<int64_t>(v) + (1L << (S - 1))) >> S)
#define RS_REF_W(S) static_cast<int32_t>((static_cast<int64_t>(w) + (1L << (S - 1))) >> S)
      // full-range x for S = 7, 8 (exact for every x); |x| <= 2^30 otherwise
      bad += ctl::fx::rshift_round_nc<7>(w) != RS_REF_W(7);
      bad += ctl::fx::rshift_round_nc<8>(w) != RS_REF_W(8);
      n += 2;
#define RS16_CHECK(S)                                                                             \
  bad += ctl::fx::rshift_round_nc<S>(v) != RS_REF(S);                                             \
  bad += ctl::fx::rshift_round_nc_lo16<S>(v) != static_cast<int16_t>(RS_REF(S));                  \
  bad += ctl::fx::rshift_round_nc_sat16<S>(v) != (RS_REF(S) > 32767 ? 32767 : (RS_REF(S) < -32768 ? -32768 : RS_REF(S)));                       \
  n += 3;
      bad += ctl::fx::rshift_round_nc<7>(v) != RS_REF(7);
      bad += ctl::fx::rshift_round_nc<8>(v) != RS_REF(8);
      n += 2;
      RS16_CHECK(9) RS16_CHECK(10) RS16_CHECK(11) RS16_CHECK(12) RS16_CHECK(13) RS16_CHECK(14)
      RS16_CHECK(15)
    }
    // 32x16 products, rounded and saturated (inline assembly): every shift 8..16, operands
    // over the whole range (a shifted by 0..31 bits, so that saturation is exercised)
    {
      const int32_t a32 = static_cast<int32_t>(x ^ (x << 13)) >> (k % 32);
#define M32_CHECK(S)                                                                               \
  {                                                                                                \
    const int64_t e = (static_cast<int64_t>(a32) * b + (static_cast<int64_t>(1) << (S - 1))) >> S; \
    bad += ctl::fx::mul32x16<S>(a32, b) != ref_sat32(e); \
    ++n;                                                                                           \
  }
      M32_CHECK(8) M32_CHECK(9) M32_CHECK(10) M32_CHECK(11) M32_CHECK(12) M32_CHECK(13) M32_CHECK(14)
      M32_CHECK(15) M32_CHECK(16)
    }
    // the short division: inside and outside its fast range
    const uint32_t dd = (k & 1) ? 13000UL + (x >> 14) % 24000UL : 1UL + (x >> (k % 31));
    const uint32_t nn = (k & 2) ? 1775000000UL + (x & 0xFFFFF) : x;
    bad += ctl::fx::div_u32(nn, dd) != nn / dd;
    // the general 16-bit division: every 16-bit divisor width, quotients of 16 and 32 bits
    const uint16_t d16 = static_cast<uint16_t>(1U + (x >> (k % 16)));
    bad += ctl::fx::div32_16(nn, d16) != nn / d16;
    bad += ctl::fx::div32_16(nn >> (k % 17), d16) != (nn >> (k % 17)) / d16;
    bad += ctl::fx::div_u32(nn, d16) != nn / d16;
    const uint32_t d24 = 65536UL + (x >> (8 + k % 24));  // 2^16 .. 2^24 + 2^16
    bad += ctl::fx::div_u32(nn, d24) != nn / d24;
    if (d24 < 16777216UL) bad += ctl::fx::div32_24(nn, d24) != nn / d24;
    bad += ctl::fx::div_u32(nn, 16777215UL - (k & 3)) != nn / (16777215UL - (k & 3));
    n += 7;
  }
  // 32x16 and 32x32 products, 32-bit saturating add and subtract at the extremes of the operands
  {
    static const int32_t ea[] = {INT32_MIN, INT32_MIN + 1, -1, 0, 1, INT32_MAX, 0x40000000L, -0x40000000L, 0x7FFF8000L};
    static const int16_t eb[] = {INT16_MIN, INT16_MIN + 1, -1, 0, 1, INT16_MAX, 0x4000, -0x4000};
    for (uint8_t i = 0; i < sizeof ea / sizeof ea[0]; ++i)
      for (uint8_t j = 0; j < sizeof eb / sizeof eb[0]; ++j) {
        const int32_t a32 = ea[i];
        const int16_t b = eb[j];
        M32_CHECK(8) M32_CHECK(9) M32_CHECK(10) M32_CHECK(11) M32_CHECK(12) M32_CHECK(13) M32_CHECK(14)
        M32_CHECK(15) M32_CHECK(16)
      }
    for (uint8_t i = 0; i < sizeof ea / sizeof ea[0]; ++i)
      for (uint8_t j = 0; j < sizeof ea / sizeof ea[0]; ++j) {
        const uint64_t e = static_cast<uint64_t>(static_cast<uint32_t>(ea[i])) * static_cast<uint32_t>(ea[j]);
        const ctl::fx::U32x2 p = ctl::fx::mul_u32x32(static_cast<uint32_t>(ea[i]), static_cast<uint32_t>(ea[j]));
        bad += p.lo != static_cast<uint32_t>(e) || p.hi != static_cast<uint32_t>(e >> 32);
        const int64_t s1 = static_cast<int64_t>(ea[i]) + ea[j], s2 = static_cast<int64_t>(ea[i]) - ea[j];
        bad += ctl::fx::add_sat32(ea[i], ea[j]) != ref_sat32(s1);
        bad += ctl::fx::sub_sat32(ea[i], ea[j]) != ref_sat32(s2);
        n += 3;
      }
  }
  // set_dt (assembly) vs set_dt_wide (C): every dt from 13,000 to 33,000 us, the edges of the
  // assembly's range, and random dt up to 2^20..2^27 us (not in profile.sh's build, whose
  // per-function figures are per benchmark step)
#ifndef CTL_PROFILE
  {
    ctl::OdometryQ oa(cfg_q.odo), ob(cfg_q.odo);
    const uint32_t k = static_cast<uint32_t>(cfg_q.odo.wheel_rate_q11);
    // and the configuration's rate_for() (plain C, the nominal rate's code) against set_dt_wide
    // over the same dt; the nominal rate itself against a division at the nominal dt
    for (uint32_t dt = 13000; dt <= 33000; ++dt) {
      bad += ctl::OdometryQProbe::check(oa, ob, dt);
      bad += ctl::OdometryQProbe::differ(ob, cfg_q.odo.rate_for(dt));
      n += 2;
    }
    ctl::OdometryQProbe::set_dt(oa, cfg_q.rate_nominal.dt_us);
    bad += ctl::OdometryQProbe::differ(oa, cfg_q.rate_nominal) + (cfg_q.rate_nominal.dt_us != ctl::kNominalInnerDtUs);
    ++n;
    const uint32_t edge[] = {1, 2, 3, 255, 256, 4095, k >> 17, (k >> 17) + 1, (k >> 17) + 2, 32766, 32767, 32768, 32769, 65535, 65536,
                             65537, 500000UL, 16777215UL, 16777216UL, 4294967295UL};
    for (uint8_t j = 0; j < sizeof edge / sizeof edge[0]; ++j) {
      bad += ctl::OdometryQProbe::check(oa, ob, edge[j]) + ctl::OdometryQProbe::differ(ob, cfg_q.odo.rate_for(edge[j]));
      n += 2;
    }
    for (uint16_t j = 0; j < 2000; ++j) {
      x = x * 1103515245UL + 12345UL;
      const uint32_t dt = 1 + (x >> (12 + j % 8));
      bad += ctl::OdometryQProbe::check(oa, ob, dt) + ctl::OdometryQProbe::differ(ob, cfg_q.odo.rate_for(dt));
      n += 2;
    }
  }
#endif
  printf("avr arithmetic self-test: %lu checks, %lu wrong\n", static_cast<unsigned long>(n), static_cast<unsigned long>(bad));
  printf("END\n");
  while (!(UCSR0A & (1 << TXC0))) {
  }
  cli();
  sleep_cpu();
  return 0;
}
