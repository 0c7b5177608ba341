// Host replay of bench.cpp's fixed-point sequence; prints the same checksum (see sequence.h).
#include <stdio.h>
#include <stdlib.h>

#include "sequence.h"

// Usage: host_check [field values printed by the AVR after "avr config"].
int main(int argc, char** argv) {
  const ctl::ControlConfig cfg =
      ctl::make_control_config(slip::RobotParams(), slip::MotorParams(), ctl::default_gains(), true);
  ctl::ControlConfigQ cfg_q(cfg);
  ctl::ReferenceSpecQ spec_q{ctl::ReferenceSpec{ctl::PathKind::kArc, 0.5f, 0.4f, 0.6f}};
  ctl::ReferenceSpecQ spec8_q{bench::kEightSpec};
  int k = 1;
#define BENCH_LOAD(f) \
  if (k < argc) cfg_q.f = static_cast<decltype(cfg_q.f)>(strtol(argv[k++], nullptr, 10));
  BENCH_CFG_FIELDS(BENCH_LOAD)
#define BENCH_LOAD_REF(f) \
  if (k < argc) spec_q.f = static_cast<decltype(+spec_q.f)>(strtol(argv[k++], nullptr, 10));
  BENCH_REF_FIELDS(BENCH_LOAD_REF)
#define BENCH_LOAD_REF8(f) \
  if (k < argc) spec8_q.f = static_cast<decltype(+spec8_q.f)>(strtol(argv[k++], nullptr, 10));
  BENCH_REF_FIELDS(BENCH_LOAD_REF8)
  if (argc > 1 && k != argc) {
    fprintf(stderr, "expected %d config values, got %d\n", k - 1, argc - 1);
    return 2;
  }
  ctl::ControllerQ qc(cfg_q);
  uint32_t h = 0;
  ctl::RefSampleQ rq{};  // the latest reference sample (held between outer steps)
  for (uint8_t i = 0; i < bench::kRuns; ++i) {
    qc.inner_step(bench::enc_r_at(i), bench::enc_l_at(i), bench::dt_us_at(i));
    if (bench::outer_due(i)) {
      rq = ctl::reference_at_q(spec_q, 25UL * i);
      qc.outer_step(rq);
    }
    h = bench::checksum_step(h, qc, rq, i);
  }
  uint32_t h8 = 0;
  for (uint8_t i = 0; i < bench::kRuns; ++i) h8 = bench::checksum_ref(h8, ctl::reference_at_q(spec8_q, bench::eight_t_ms(i)));
  printf("host fixed-point checksum %08lx %08lx %08lx %08lx\n", static_cast<unsigned long>(h), static_cast<unsigned long>(h8),
         static_cast<unsigned long>(bench::checksum_trig()), static_cast<unsigned long>(bench::checksum_long()));
  return 0;
}
