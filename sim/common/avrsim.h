/*
 * avrsim: the one libsimavr harness layer of this project (C, usable from C and C++).
 *
 *   - loads a firmware ELF into a simulated ATmega2560 at the board's clock (F_CPU, board.h);
 *   - steps the core one instruction at a time with ONE set of cycle corrections that make
 *     simavr 1.6's interrupt timing that of the ATmega2560 (sim/common/README.md derives each
 *     from the datasheet and from simavr's source);
 *   - counts the cycles of every interrupt invocation per vector (nesting aware);
 *   - reads the ELF symbol table (addresses of firmware variables and functions).
 *
 * Register and bit names: sim/common/avr_regs.h (avr-libc's own iom2560.h, as data addresses).
 * Every harness that links libsimavr (sim/isr_bench, sim/fil, bench/control_avr/profile.c,
 * bench/plant/avr_cycles_harness.c) is built by host_tools/_build.py, which links avrsim.c in.
 */
#ifndef SIM_COMMON_AVRSIM_H
#define SIM_COMMON_AVRSIM_H

#include <stddef.h>
#include <stdint.h>

#include <simavr/sim_avr.h>

#include "board.h" /* F_CPU: the board's clock */

#ifdef __cplusplus
extern "C" {
#endif

#define AVRSIM_MCU "atmega2560"
#define AVRSIM_F_CPU_HZ ((uint32_t)F_CPU)

/* ---- the corrections (sim/common/README.md, "Cycle corrections") ---------------------------
 * 1. Interrupt response: ATmega2560 datasheet 7.8.1, "five clock cycles minimum" (the 3-byte
 *    PC is pushed); simavr 1.6 vectors at zero cost. Added at every vectoring.
 * 2. Wake-up from sleep: 7.8.1, the response "is increased by five clock cycles" when the MCU
 *    sleeps (plus the sleep mode's start-up time: none in Idle, the firmware's mode); simavr
 *    adds nothing. Added when the core vectors out of sleep.
 * 3. One instruction after RETI (and SEI, or any write that sets SREG.I): the hardware executes
 *    exactly one more instruction before a pending interrupt; simavr 1.6 executes two. The step
 *    after such an instruction lets the next instruction be the last. A RETI that finds SREG.I
 *    already set (the return of an ISR_NOBLOCK handler) leaves simavr with no wait at all: an
 *    interrupt raised during it would be served in the same step; the step defers it by one
 *    instruction as well.
 * Not corrected, because simavr already charges the datasheet's figure (the self-test checks):
 *    RETI 5 cycles (3-byte PC popped), the vector's JMP 3 cycles. */
/* ---- ADC inputs (sim/common/README.md, "ADC") ---------------------------------------------
 * 4. Conversion: the ATmega2560 gives ADC = Vin 1024 / Vref (datasheet, "ADC Conversion Result"),
 *    its ideal first transition at 0.5 LSB ("ADC Accuracy Definitions"), i.e. rounded; simavr 1.6 computes value 1023 / vref
 *    truncated, from integer millivolts held in 16 bits. avrsim_adc_input hands simavr the input
 *    and AVcc in units of Vref / (1024 AVRSIM_ADC_SUBCOUNTS) (1023 x 64 fits the 16 bits), so that
 *    its arithmetic gives the datasheet's code to 1/64 count (AVcc reference only: the internal
 *    1.1 V / 2.56 V references are not rescaled).
 * 5. Sample instant: the hardware samples 1.5 ADC clocks after ADSC is set ("Prescaling and
 *    Conversion Timing"; 13.5 for the first conversion after ADEN); simavr reads its input value when the program reads ADCL.
 *    avrsim_adc_sampler calls the harness back at the sample instant of every conversion, which
 *    then sets that channel's input once (held until the next conversion of that channel). */
#define AVRSIM_ADC_SUBCOUNTS 64u
#define AVRSIM_ADC_SH_CLOCKS_X2 3u /* 1.5 ADC clocks */

#define AVRSIM_IRQ_RESPONSE_CYCLES 5u
#define AVRSIM_WAKE_CYCLES 5u
#define AVRSIM_RETI_CYCLES 5u /* as simavr charges it: 1 + 1 + 3-byte PC */

#define AVRSIM_VECTORS 64
#define AVRSIM_VECTOR_TABLE_END 0xE4u /* 57 vectors x 4 bytes (byte address) */
#define AVRSIM_MAX_NESTING 16

typedef struct avrsim_isr_stat {
    unsigned long calls;
    unsigned long max_cycles;
    double sum_cycles;
} avrsim_isr_stat_t;

typedef struct avrsim_open_isr {
    int vector;
    avr_cycle_count_t start;  /* cycle at which the core vectored (before the response) */
    avr_cycle_count_t nested; /* cycles of ISRs nested inside this one */
} avrsim_open_isr_t;

typedef struct avrsim {
    avr_t *avr;
    int asleep; /* the core was sleeping after the previous step */
    /* per-vector statistics of finished invocations: response (+ wake-up), JMP, body, RETI,
     * without the cycles of ISRs nested in it */
    avrsim_isr_stat_t isr[AVRSIM_VECTORS];
    avrsim_open_isr_t open[AVRSIM_MAX_NESTING];
    int depth;
    unsigned long nested_calls; /* invocations that started inside another ISR */
    unsigned long wakeups;      /* vectorings out of sleep */
    /* what the last avrsim_step() did */
    int entered;                     /* vector entered, 0 if none */
    int left;                        /* vector whose invocation a RETI ended, 0 if none */
    unsigned long left_cycles;       /* that invocation's own cycles */
    avr_flashaddr_t pc_before;       /* program address of the step (byte address) */
    avr_cycle_count_t cycle_before;  /* cycle count before the step */
    /* avrsim_adc_sampler */
    void (*adc_fn)(void *ctx, int channel, avr_cycle_count_t when);
    void *adc_ctx;
    int adc_channel;        /* single-ended channel of the conversion in progress, -1 if other */
    unsigned long adc_conversions;
} avrsim_t;

/* Loads `elf_path` into a new ATmega2560 at AVRSIM_F_CPU_HZ, simavr's logging off. Returns 0,
 * or -1 with a message in err. */
int avrsim_open(avrsim_t *s, const char *elf_path, char *err, size_t err_len);
/* A new ATmega2560 at AVRSIM_F_CPU_HZ with erased flash (all 0xFF), for a harness that writes
 * the flash itself (a bootloader image); simavr's logging off. Returns 0, or -1 with a message. */
int avrsim_open_blank(avrsim_t *s, char *err, size_t err_len);

/* One instruction (or one sleeping interval up to the next simavr cycle timer) with the
 * corrections above and the ISR accounting. Returns the core state (cpu_Running, ...). */
int avrsim_step(avrsim_t *s);

/* Makes a sleeping core stop at `cycle` (a simavr cycle timer there; one at a time, a new
 * call replaces it), for harnesses that step with their own loop. */
void avrsim_stop_at(avrsim_t *s, avr_cycle_count_t cycle);

/* Steps until the cycle count reaches `cycle`. A cycle timer at `cycle` makes a sleeping core
 * stop there, so stimuli applied after the call happen at that cycle. */
void avrsim_run_until(avrsim_t *s, avr_cycle_count_t cycle);

/* Clears the per-vector statistics (not the invocations in progress). */
void avrsim_clear_isr_stats(avrsim_t *s);

/* Forgets the invocations in progress (a reset abandons them). */
void avrsim_abandon_isrs(avrsim_t *s);

/* ADC (corrections 4 and 5): sets simavr's AVcc to the scaled reference and calls
 * fn(ctx, channel, cycle) at the sample instant of every single-ended conversion (channel 0-15);
 * fn then calls avrsim_adc_input. Call once after avrsim_open; a reset keeps it. */
void avrsim_adc_sampler(avrsim_t *s, void (*fn)(void *ctx, int channel, avr_cycle_count_t when), void *ctx);
/* Input of single-ended channel `channel` as a fraction of AVcc (clipped to [0, 1]). */
void avrsim_adc_input(avrsim_t *s, int channel, double vin_over_avcc);

/* 16-bit little-endian value in data space. */
uint16_t avrsim_rd16(const avrsim_t *s, uint16_t addr);

/* Seconds of simulated time of a cycle count. */
double avrsim_seconds(avr_cycle_count_t cycles);

/* ELF symbol table. Value of symbol `name` (flash: byte address; data: the 0x80xxxx address
 * avr-gcc gives it); -1 when absent or the file is not a 32-bit ELF. */
long avrsim_symbol(const char *elf_path, const char *name);
/* Data-space address (0x80xxxx & 0xFFFF) of a variable; -1 when absent. */
long avrsim_data_symbol(const char *elf_path, const char *name);

/* Calls fn(value, size, is_func, name, ctx) for every named symbol; returns -1 when the file
 * cannot be read as a 32-bit ELF, else 0. */
typedef void (*avrsim_symbol_fn)(unsigned long value, unsigned long size, int is_func,
                                 const char *name, void *ctx);
int avrsim_each_symbol(const char *elf_path, avrsim_symbol_fn fn, void *ctx);

#ifdef __cplusplus
}
#endif

#endif /* SIM_COMMON_AVRSIM_H */
