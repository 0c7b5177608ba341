/* simavr harness for bench/plant/avr_cycles.sh (sim/common): runs an ATmega2560 ELF and prints
 * the CPU cycle count at every write to GPIOR0, and the differences. */
#include <stdio.h>
#include <stdlib.h>

#include <simavr/sim_avr.h>
#include <simavr/sim_io.h>

#include "avrsim.h"
#include "avr_regs.h"

static uint64_t g_last;
static int g_have_last;

static void on_marker(struct avr_t* avr, avr_io_addr_t addr, uint8_t v, void* param) {
  (void)addr;
  (void)param;
  if (g_have_last)
    printf("marker %u: cycle %llu (+%llu since the previous marker)\n", v,
           (unsigned long long)avr->cycle, (unsigned long long)(avr->cycle - g_last));
  else
    printf("marker %u: cycle %llu\n", v, (unsigned long long)avr->cycle);
  g_last = avr->cycle;
  g_have_last = 1;
}

int main(int argc, char** argv) {
  if (argc != 2) {
    fprintf(stderr, "usage: %s firmware.elf\n", argv[0]);
    return 2;
  }
  avrsim_t sim;
  char err[256];
  if (avrsim_open(&sim, argv[1], err, sizeof err)) {
    fprintf(stderr, "avr_cycles_harness: %s\n", err);
    return 2;
  }
  avr_register_io_write(sim.avr, GPIOR0, on_marker, NULL);
  int state = cpu_Running;
  for (long i = 0; i < 10000000 && state != cpu_Done && state != cpu_Crashed; ++i) state = avrsim_step(&sim);
  return state == cpu_Done ? 0 : 1;
}
