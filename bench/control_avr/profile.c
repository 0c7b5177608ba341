/* Cycle profile of the control benchmark (libsimavr, sim/common): runs an ATmega2560 ELF to its
 * end and prints, for every program address that executed, the CPU cycles spent there ("pc
 * cycles", pc as a byte address in hex). bench/control_avr/profile.sh maps the addresses to
 * source lines, and the cycles spent in each CTL_PROBE region ("region n cycles"). The
 * benchmark uses no interrupts, so sim/common's interrupt corrections never apply.
 * Usage: profile bench.elf > pcs.txt */
#include <stdio.h>
#include <stdlib.h>

#include <simavr/sim_avr.h>

#include "avrsim.h"
#include "avr_regs.h"

int main(int argc, char **argv) {
    if (argc < 2) { fprintf(stderr, "usage: %s firmware.elf\n", argv[0]); return 2; }
    avrsim_t sim;
    char err[256];
    if (avrsim_open(&sim, argv[1], err, sizeof err)) { fprintf(stderr, "profile: %s\n", err); return 2; }
    avr_t *avr = sim.avr;
    const size_t n = 256u * 1024u;
    unsigned long long *cyc = calloc(n, sizeof *cyc);
    unsigned long long region[256] = {0};
    if (!cyc) return 2;
    for (;;) {
        const int st = avrsim_step(&sim);
        const avr_cycle_count_t d = avr->cycle - sim.cycle_before;
        if (sim.pc_before < n) cyc[sim.pc_before] += d;
        region[avr->data[GPIOR0]] += d; /* CTL_PROBE region marker */
        if (st == cpu_Done || st == cpu_Crashed || avr->state == cpu_Sleeping) break;
    }
    for (int r = 1; r < 256; ++r)
        if (region[r]) printf("region %d %llu\n", r, region[r]);
    for (size_t pc = 0; pc < n; ++pc)
        if (cyc[pc]) printf("%zx %llu\n", pc, cyc[pc]);
    free(cyc);
    return 0;
}
