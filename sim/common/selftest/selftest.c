/* Self-test of the avrsim corrections (sim/common/README.md): runs timing.S and checks each
 * figure against the ATmega2560 datasheet. Prints one PASS/FAIL line per check and a closing
 * "N passed, M failed" line; exit status 1 when a check failed.
 * Usage: selftest timing.elf */
#include <stdio.h>
#include <string.h>

#include <simavr/avr_ioport.h>
#include <simavr/sim_avr.h>
#include <simavr/sim_cycle_timers.h>

#include "avrsim.h"
#include "avr_regs.h"

static avrsim_t sim;
static avr_irq_t *pd0, *pd1, *pd2;
static int passed, failed;

static void check(int ok, const char *what, long got, long want) {
    printf("%s  %s: %ld (datasheet %ld)\n", ok ? "PASS" : "FAIL", what, got, want);
    if (ok) ++passed; else ++failed;
}

static int run_to_phase(int phase) {
    avr_cycle_count_t end = sim.avr->cycle + 100000;
    while (sim.avr->data[GPIOR0] != phase && sim.avr->cycle < end && sim.avr->state != cpu_Done &&
           sim.avr->state != cpu_Crashed)
        avrsim_step(&sim);
    if (sim.avr->data[GPIOR0] != phase) { printf("FAIL  phase %d never reached\n", phase); ++failed; return 0; }
    return 1;
}

static void steps(int n) { while (n-- > 0) avrsim_step(&sim); }

static avr_cycle_count_t raise_pd0(avr_t *avr, avr_cycle_count_t when, void *param) {
    (void)avr; (void)when; (void)param;
    avr_raise_irq(pd0, 1);
    return 0;
}

static void low(void) { avr_raise_irq(pd0, 0); avr_raise_irq(pd1, 0); avr_raise_irq(pd2, 0); }

/* cycles of the one INT0 invocation since the last clear */
static long int0_cycles(void) {
    return sim.isr[INT0_vect].calls == 1 ? (long)sim.isr[INT0_vect].max_cycles : -1;
}

int main(int argc, char **argv) {
    char err[256];
    if (argc != 2) { fprintf(stderr, "usage: %s timing.elf\n", argv[0]); return 2; }
    if (avrsim_open(&sim, argv[1], err, sizeof err)) { fprintf(stderr, "selftest: %s\n", err); return 2; }
    pd0 = avr_io_getirq(sim.avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 0);
    pd1 = avr_io_getirq(sim.avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 1);
    pd2 = avr_io_getirq(sim.avr, AVR_IOCTL_IOPORT_GETIRQ('D'), 2);
    const long int2_reti = avrsim_symbol(argv[1], "isr_int2_reti");
    if (int2_reti < 0) { fprintf(stderr, "selftest: no isr_int2_reti in %s\n", argv[1]); return 2; }
    low();
    const long body0 = 2, body1 = 1, jmp = 3;
    const long awake0 = AVRSIM_IRQ_RESPONSE_CYCLES + jmp + body0 + AVRSIM_RETI_CYCLES;

    if (!run_to_phase(1)) return 1;
    steps(20); /* inside the INC chain */
    avrsim_clear_isr_stats(&sim);
    avr_raise_irq(pd0, 1);
    avr_raise_irq(pd1, 1);
    steps(40);
    check(sim.avr->data[22] - sim.avr->data[21] == 1,
          "main instructions between RETI and the next pending interrupt", sim.avr->data[22] - sim.avr->data[21], 1);
    check(int0_cycles() == awake0, "INT0 response + JMP + 2-cycle body + RETI, core awake", int0_cycles(), awake0);
    check(sim.isr[INT1_vect].max_cycles == (unsigned long)(awake0 - body0 + body1),
          "INT1 response + JMP + 1-cycle body + RETI", (long)sim.isr[INT1_vect].max_cycles, awake0 - body0 + body1);

    low();
    if (!run_to_phase(2)) return 1;
    avrsim_run_until(&sim, sim.avr->cycle + 200); /* asleep */
    check(sim.avr->state == cpu_Sleeping, "core asleep in phase 2", sim.avr->state == cpu_Sleeping, 1);
    avrsim_clear_isr_stats(&sim);
    avr_raise_irq(pd0, 1); /* between two steps */
    steps(10);
    check(int0_cycles() == awake0 + (long)AVRSIM_WAKE_CYCLES, "INT0 waking the core (stimulus between steps)",
          int0_cycles(), awake0 + AVRSIM_WAKE_CYCLES);
    check(sim.avr->data[23] == 2, "ISR before the instruction after SLEEP (phase register seen by the ISR)",
          sim.avr->data[23], 2);

    low();
    if (!run_to_phase(3)) return 1;
    avrsim_clear_isr_stats(&sim);
    avr_cycle_timer_register(sim.avr, 500, raise_pd0, NULL);
    avrsim_run_until(&sim, sim.avr->cycle + 600);
    check(int0_cycles() == awake0 + (long)AVRSIM_WAKE_CYCLES, "INT0 waking the core (simavr cycle timer)",
          int0_cycles(), awake0 + AVRSIM_WAKE_CYCLES);

    low();
    if (!run_to_phase(4)) return 1;
    steps(10);
    avr_raise_irq(pd0, 1); /* pending while interrupts are off */
    avrsim_run_until(&sim, sim.avr->cycle + 100);
    check(sim.avr->data[21] == 1, "main instructions after SEI before a pending interrupt", sim.avr->data[21], 1);

    low();
    if (!run_to_phase(5)) return 1;
    steps(10);
    avrsim_clear_isr_stats(&sim);
    avr_raise_irq(pd0, 1);
    if (!run_to_phase(6)) return 1;
    check(int0_cycles() == awake0 + (long)AVRSIM_WAKE_CYCLES, "SEI; SLEEP with INT0 pending: sleeps and wakes at once",
          int0_cycles(), awake0 + AVRSIM_WAKE_CYCLES);

    low();
    steps(20); /* inside the INC chain */
    avr_raise_irq(pd2, 1);
    for (int i = 0; i < 40 && (long)sim.avr->pc != int2_reti; ++i) avrsim_step(&sim);
    avrsim_clear_isr_stats(&sim);
    avr_cycle_timer_register(sim.avr, 1, raise_pd0, NULL); /* due during the RETI's 5 cycles */
    steps(40);
    check(sim.avr->data[21] - sim.avr->data[24] == 1,
          "main instructions between a RETI that finds SREG.I set and an interrupt raised during it",
          sim.avr->data[21] - sim.avr->data[24], 1);
    check(int0_cycles() == awake0, "INT0 raised during that RETI: counted, response + JMP + body + RETI",
          int0_cycles(), awake0);

    printf("avrsim self-test: %d passed, %d failed\n", passed, failed);
    return failed ? 1 : 0;
}
