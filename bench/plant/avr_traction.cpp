// ATmega2560 program for bench/plant/avr_cycles.sh: calls the firmware-side traction functions
// between GPIOR0 markers; the simavr harness (avr_cycles_harness.c) prints the cycles between
// markers. Inputs are volatile so nothing is folded away; the functions live in traction.cpp
// (another translation unit, no LTO), so the calls are real.
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>

#include <slipmodel/traction.h>

static constexpr slip::TractionQ kQ = slip::traction_q(slip::table_ii2());
volatile int32_t g_lat_q16 = 98304;  // 1.5 N
volatile double g_lat_n = 1.5;
volatile int32_t g_sink_q;
volatile double g_sink_f;

int main() {
  const slip::RobotParams p = slip::table_ii2();
  GPIOR0 = 1;  // marker 1 -> 2: empty (marker cost)
  GPIOR0 = 2;
  {
    const slip::NormalForcesQ n = slip::normal_forces_q16(kQ, g_lat_q16);
    g_sink_q = slip::tau_max_q16(kQ, n.N_r_q16) + slip::tau_max_q16(kQ, n.N_l_q16);
  }
  GPIOR0 = 3;  // 2 -> 3: fixed point, normal forces + tau_max of both wheels
  {
    const slip::NormalForces n = slip::normal_forces(p, g_lat_n);
    g_sink_f = slip::tau_max(p, n.N_r) + slip::tau_max(p, n.N_l);
  }
  GPIOR0 = 4;  // 3 -> 4: float, the same
  cli();
  sleep_enable();
  sleep_cpu();
  for (;;) {
  }
}
