/*
 * Encoder ISR cycle harness (libsimavr). Loads an ATmega2560 ELF that uses src/encoder_isr.S,
 * drives PD0..PD3 with quadrature signals at controlled edge rates and reports:
 *   - cycles per edge of every encoder ISR invocation (response + JMP + body + RETI), per path,
 *     with the core awake and woken from sleep;
 *   - for a sweep of edge rates (both wheels together): counts lost, illegal transitions and
 *     the CPU share taken by the ISRs.
 * Cycle accounting and the corrections that make simavr 1.6's interrupt timing that of the
 * ATmega2560: sim/common (README.md there).
 * Run it on the real firmware.elf: its other interrupts (1 kHz tick, Timer5 overflow, USART2,
 * ADC) and its interrupt-free sections then take part in the lossless-rate measurement.
 * Usage: isr_bench FIRMWARE.elf [--trace]
 */
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <simavr/avr_ioport.h>
#include <simavr/sim_avr.h>

#include "avrsim.h"
#include "board_sim.h"

static avrsim_t sim;
static avr_t *avr;
static avr_irq_t *pin_irq[2][2]; /* [wheel: 0 left, 1 right][channel: 0 A, 1 B] */
static const int enc_bit[2][2] = {{ENC_LEFT_A_BIT, ENC_LEFT_B_BIT}, {ENC_RIGHT_A_BIT, ENC_RIGHT_B_BIT}};
static uint16_t a_raw_l, a_raw_r, a_ill_l, a_ill_r;

/* per-invocation bookkeeping */
static int in_isr; /* an encoder ISR is running */
static uint16_t isr_pre[4];
static int isr_from_sleep;
static unsigned long n_isr[8], hist_min[8], hist_max[8];
static double hist_sum[8];
static unsigned long n_wake, wake_min, wake_max; /* invocations that woke the core */
static avr_cycle_count_t isr_cycles_total;
static int trace;

static uint16_t data_symbol(const char *elf, const char *name) {
    long a = avrsim_data_symbol(elf, name);
    if (a < 0) { fprintf(stderr, "symbol %s not found in %s\n", name, elf); exit(2); }
    return (uint16_t)a;
}

static uint16_t rd16(uint16_t a) { return avrsim_rd16(&sim, a); }

/* Path classification of one invocation from the counter changes. */
enum { P_NONE, P_INC_L, P_DEC_L, P_ILL_L, P_INC_R, P_DEC_R, P_ILL_R, P_OTHER };
static const char *path_name[8] = {"no change", "left +1", "left -1", "left illegal",
                                   "right +1", "right -1", "right illegal", "other"};

/* longest stretch with interrupts disabled outside the encoder ISRs (other ISRs, cli sections) */
static avr_cycle_count_t ioff_start, ioff_max;
static avr_flashaddr_t ioff_pc, ioff_max_pc;
static int ioff_active;

static void step(void) {
    const unsigned long wakeups0 = sim.wakeups;
    avrsim_step(&sim);
    if (trace && in_isr)
        printf("  trace pc=%05x op=%04x cycles=%llu\n", (unsigned)sim.pc_before,
               (unsigned)(avr->flash[sim.pc_before] | (avr->flash[sim.pc_before + 1] << 8)),
               (unsigned long long)(avr->cycle - sim.cycle_before));
    if (SIM_IS_ENC_VECTOR(sim.left) && in_isr) {
        unsigned long d = sim.left_cycles;
        uint16_t post[4] = {rd16(a_raw_l), rd16(a_raw_r), rd16(a_ill_l), rd16(a_ill_r)};
        int path = P_NONE, changed = 0;
        if (post[0] != isr_pre[0]) { path = (uint16_t)(post[0] - isr_pre[0]) == 1 ? P_INC_L : P_DEC_L; changed++; }
        if (post[1] != isr_pre[1]) { path = (uint16_t)(post[1] - isr_pre[1]) == 1 ? P_INC_R : P_DEC_R; changed++; }
        if (post[2] != isr_pre[2]) { path = P_ILL_L; changed++; }
        if (post[3] != isr_pre[3]) { path = P_ILL_R; changed++; }
        if (changed > 1) path = P_OTHER;
        if (isr_from_sleep) {  /* kept apart: the wake-up adds to the response */
            if (n_wake == 0 || d < wake_min) wake_min = d;
            if (d > wake_max) wake_max = d;
            n_wake++;
        } else {
            if (n_isr[path] == 0 || d < hist_min[path]) hist_min[path] = d;
            if (d > hist_max[path]) hist_max[path] = d;
            hist_sum[path] += (double)d;
            n_isr[path]++;
        }
        isr_cycles_total += d;
        in_isr = 0;
        if (trace) { printf("  trace: end of ISR, %lu cycles incl. response\n", d); trace = 0; }
    }
    if (!in_isr) {
        if (!avr->sreg[S_I] && !ioff_active) { ioff_active = 1; ioff_start = sim.cycle_before; ioff_pc = sim.pc_before; }
        else if (avr->sreg[S_I] && ioff_active) {
            ioff_active = 0;
            if (avr->cycle - ioff_start > ioff_max) { ioff_max = avr->cycle - ioff_start; ioff_max_pc = ioff_pc; }
        }
    }
    if (SIM_IS_ENC_VECTOR(sim.entered) && !in_isr) {
        in_isr = 1;
        isr_from_sleep = sim.wakeups != wakeups0;
        isr_pre[0] = rd16(a_raw_l); isr_pre[1] = rd16(a_raw_r);
        isr_pre[2] = rd16(a_ill_l); isr_pre[3] = rd16(a_ill_r);
        if (trace) printf("  trace: vector %d at cycle %llu (response charged)\n", sim.entered, (unsigned long long)sim.cycle_before);
    }
}

static void run_until(avr_cycle_count_t c) {
    avrsim_stop_at(&sim, c);
    while (avr->cycle < c) step();
}

/* Gray sequence (B,A): forward when A leads B = 00,01,11,10 */
static const uint8_t gray[4] = {0, 1, 3, 2};
static int pos_l, pos_r;  /* Gray positions of the generated signals */

static void drive(int wheel, int pos) {
    uint8_t s = gray[pos & 3];
    avr_raise_irq(pin_irq[wheel][0], s & 1);
    avr_raise_irq(pin_irq[wheel][1], (s >> 1) & 1);
}

static void reset_stats(void) {
    n_wake = wake_min = wake_max = 0;
    memset(n_isr, 0, sizeof n_isr); memset(hist_min, 0, sizeof hist_min);
    memset(hist_max, 0, sizeof hist_max); memset(hist_sum, 0, sizeof hist_sum);
    isr_cycles_total = 0;
}

/* One run: n edges per wheel at rate_per_wheel edges/s, right wheel phase-shifted by `phase`
 * of an edge interval. Generated direction: the wheel's "A leads B" sense (dir_l, dir_r = +-1).
 * Returns 1 if lossless. */
static int run_rate(double rate_per_wheel, double phase, long n, int dir_l, int dir_r,
                    int sign_l, int sign_r, int verbose) {
    uint16_t l0 = rd16(a_raw_l), r0 = rd16(a_raw_r), il0 = rd16(a_ill_l), ir0 = rd16(a_ill_r);
    double interval = (double)AVRSIM_F_CPU_HZ / rate_per_wheel;
    double t0 = (double)avr->cycle + 100.0;
    double next_l = t0, next_r = t0 + phase * interval;
    long k_l = 0, k_r = 0;
    reset_stats();
    avr_cycle_count_t start = avr->cycle;
    while (k_l < n || k_r < n) {
        if (k_l < n && (double)avr->cycle >= next_l) { pos_l += dir_l; drive(0, pos_l); k_l++; next_l += interval; }
        if (k_r < n && (double)avr->cycle >= next_r) { pos_r += dir_r; drive(1, pos_r); k_r++; next_r += interval; }
        if (sim.asleep) {  /* wake the simulation (not the core) at the next edge */
            double next = k_l < n && (k_r >= n || next_l < next_r) ? next_l : next_r;
            avrsim_stop_at(&sim, (avr_cycle_count_t)next + 1);
        }
        step();
    }
    run_until(avr->cycle + 2000); /* let pending ISRs finish */
    avr_cycle_count_t span = avr->cycle - start;
    int16_t got_l = (int16_t)(rd16(a_raw_l) - l0), got_r = (int16_t)(rd16(a_raw_r) - r0);
    long exp_l = (long)sign_l * dir_l * n, exp_r = (long)sign_r * dir_r * n;
    uint16_t ill_l = (uint16_t)(rd16(a_ill_l) - il0), ill_r = (uint16_t)(rd16(a_ill_r) - ir0);
    int ok = got_l == exp_l && got_r == exp_r && ill_l == 0 && ill_r == 0;
    if (verbose)
        printf("%9.0f %6.2f %7ld %7d %7ld %7d %6u %6u %6.1f%%  %s\n", 2.0 * rate_per_wheel, phase,
               exp_l, got_l, exp_r, got_r, ill_l, ill_r,
               100.0 * (double)isr_cycles_total / (double)span,
               ok ? "lossless" : ((ill_l || ill_r) ? "LOST, flagged as illegal" : "LOST, NOT flagged"));
    return ok;
}

static void print_wake(void) {
    if (n_wake) printf("%-15s %8lu %6lu %6lu\n", "woken (any)", n_wake, wake_min, wake_max);
}

int main(int argc, char **argv) {
    if (argc < 2) { fprintf(stderr, "usage: %s firmware.elf [--trace]\n", argv[0]); return 2; }
    trace = argc > 2 && strcmp(argv[2], "--trace") == 0;
    char err[256];
    if (avrsim_open(&sim, argv[1], err, sizeof err)) { fprintf(stderr, "isr_bench: %s\n", err); return 2; }
    avr = sim.avr;
    a_raw_l = data_symbol(argv[1], "enc_raw_l");
    a_raw_r = data_symbol(argv[1], "enc_raw_r");
    a_ill_l = data_symbol(argv[1], "enc_ill_l");
    a_ill_r = data_symbol(argv[1], "enc_ill_r");
    /* boot with all encoder lines low, then wait for the firmware to enable their interrupts */
    for (int w = 0; w < 2; w++)
        for (int ch = 0; ch < 2; ch++) {
            pin_irq[w][ch] = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ(SIM_ENC_PORT_LETTER), enc_bit[w][ch]);
            avr_raise_irq(pin_irq[w][ch], 0);
        }
    int trace_req = trace; trace = 0;
    run_until(AVRSIM_F_CPU_HZ / 50u); /* 20 ms */
    if ((avr->data[EIMSK] & ENC_INT_MASK) != ENC_INT_MASK) {
        fprintf(stderr, "firmware did not enable the encoder interrupts within 20 ms (EIMSK=%02x)\n", avr->data[EIMSK]);
        return 1;
    }
    int sign_l = 1, sign_r = 1;
    {   /* learn each wheel's sign convention (ENC_*_REVERSED) from one slow forward step */
        drive(0, pos_l); drive(1, pos_r);          /* settle: pull-ups may have moved the lines */
        run_until(avr->cycle + 4000);
        uint16_t l0 = rd16(a_raw_l), r0 = rd16(a_raw_r);
        pos_l++; drive(0, pos_l); pos_r++; drive(1, pos_r);
        run_until(avr->cycle + 4000);
        sign_l = (int16_t)(rd16(a_raw_l) - l0); sign_r = (int16_t)(rd16(a_raw_r) - r0);
        if ((sign_l != 1 && sign_l != -1) || (sign_r != 1 && sign_r != -1)) {
            fprintf(stderr, "single step not counted as +-1 (%d, %d)\n", sign_l, sign_r);
            return 1;
        }
    }
    trace = trace_req;
    ioff_max = 0; /* boot runs with interrupts off: not part of the measurement */

    printf("# encoder ISR cycles per edge, response + JMP + body + RETI (sim/common corrections: response %u,\n"
           "# +%u when the edge wakes the core from sleep; one main instruction after RETI)\n",
           AVRSIM_IRQ_RESPONSE_CYCLES, AVRSIM_WAKE_CYCLES);
    run_rate(2000.0, 0.5, 400, +1, +1, sign_l, sign_r, 0);
    run_rate(2000.0, 0.5, 400, -1, -1, sign_l, sign_r, 0);
    /* remember the per-path figures of the slow runs (both directions) */
    printf("%-15s %8s %6s %6s %7s   (core awake; edges that woke it: last line)\n", "path", "calls", "min", "max", "mean");
    reset_stats();
    run_rate(2000.0, 0.5, 400, +1, +1, sign_l, sign_r, 0);
    for (int p = 0; p < 8; p++) if (n_isr[p])
        printf("%-15s %8lu %6lu %6lu %7.2f\n", path_name[p], n_isr[p], hist_min[p], hist_max[p], hist_sum[p] / n_isr[p]);
    print_wake();
    run_rate(2000.0, 0.5, 400, -1, -1, sign_l, sign_r, 0);
    for (int p = 0; p < 8; p++) if (n_isr[p])
        printf("%-15s %8lu %6lu %6lu %7.2f\n", path_name[p], n_isr[p], hist_min[p], hist_max[p], hist_sum[p] / n_isr[p]);
    print_wake();
    {   /* illegal path: both channels of both wheels jump two Gray steps at once */
        reset_stats();
        pos_l += 2; drive(0, pos_l); run_until(avr->cycle + 2000);
        pos_r += 2; drive(1, pos_r); run_until(avr->cycle + 2000);
        for (int p = 0; p < 8; p++) if (n_isr[p])
            printf("%-15s %8lu %6lu %6lu %7.2f\n", path_name[p], n_isr[p], hist_min[p], hist_max[p], hist_sum[p] / n_isr[p]);
    }

    printf("\n# edge-rate sweep, both wheels at the same rate; phase = right-wheel offset in edge intervals\n");
    printf("# (0.00 = both wheels' edges coincide: worst case)\n");
    printf("%9s %6s %7s %7s %7s %7s %6s %6s %7s  %s\n", "edges/s", "phase", "exp_l", "got_l", "exp_r", "got_r",
           "ill_l", "ill_r", "isr_cpu", "verdict");
    static const double rates[] = {21700, 50000, 100000, 150000, 200000, 250000, 300000, 330000, 360000, 400000, 500000, 700000};
    double max_ok_coincident = 0, max_ok_spread = 0;
    int all_flagged = 1;
    for (unsigned i = 0; i < sizeof rates / sizeof rates[0]; i++) {
        for (int ph = 0; ph < 2; ph++) {
            double phase = ph ? 0.37 : 0.0;
            int ok = run_rate(rates[i] / 2.0, phase, 6000, +1, +1, sign_l, sign_r, 1);
            if (ok) { if (ph) { if (rates[i] > max_ok_spread) max_ok_spread = rates[i]; } else if (rates[i] > max_ok_coincident) max_ok_coincident = rates[i]; }
        }
    }
    (void)all_flagged;
    /* fine search for the limit, coincident edges (worst case) */
    double lo = max_ok_coincident, hi = lo * 2.0;
    for (int it = 0; it < 12; it++) {
        double mid = 0.5 * (lo + hi);
        if (run_rate(mid / 2.0, 0.0, 6000, +1, +1, sign_l, sign_r, 0)) lo = mid; else hi = mid;
    }
    printf("\nmax lossless edge rate, both wheels together, coincident edges: %.0f edges/s\n", lo);
    printf("longest interrupt-disabled stretch outside the encoder ISRs: %llu cycles, from pc 0x%05x\n",
           (unsigned long long)ioff_max, (unsigned)ioff_max_pc);
    double lo2 = max_ok_spread, hi2 = lo2 * 2.0;
    for (int it = 0; it < 12; it++) {
        double mid = 0.5 * (lo2 + hi2);
        if (run_rate(mid / 2.0, 0.37, 6000, +1, +1, sign_l, sign_r, 0)) lo2 = mid; else hi2 = mid;
    }
    printf("max lossless edge rate, both wheels together, edges spread (phase 0.37): %.0f edges/s\n", lo2);
    return 0;
}
