/* avrsim: loading, corrected stepping and ISR accounting (avrsim.h; corrections derived in
 * sim/common/README.md). */
#include "avrsim.h"

#include <elf.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <simavr/avr_adc.h>
#include <simavr/sim_cycle_timers.h>
#include <simavr/sim_elf.h>
#include <simavr/sim_interrupts.h>

#include "avr_regs.h"

#define OP_RETI 0x9518u
#define OP_SLEEP 0x9588u

/* The harnesses pace the simulation themselves; simavr's default would usleep() to keep a
 * sleeping core in step with the wall clock. */
static void no_wall_sleep(avr_t *avr, avr_cycle_count_t how_long) {
    (void)avr;
    (void)how_long;
}

int avrsim_open_blank(avrsim_t *s, char *err, size_t err_len) {
    memset(s, 0, sizeof *s);
    s->avr = avr_make_mcu_by_name(AVRSIM_MCU);
    if (!s->avr) {
        snprintf(err, err_len, "libsimavr has no %s", AVRSIM_MCU);
        return -1;
    }
    avr_init(s->avr);
    s->avr->frequency = AVRSIM_F_CPU_HZ;
    s->avr->log = 0;
    s->avr->sleep = no_wall_sleep;
    return 0;
}

int avrsim_open(avrsim_t *s, const char *elf_path, char *err, size_t err_len) {
    elf_firmware_t fw;
    memset(&fw, 0, sizeof fw);
    if (elf_read_firmware(elf_path, &fw)) {
        memset(s, 0, sizeof *s);
        snprintf(err, err_len, "libsimavr cannot load %s", elf_path);
        return -1;
    }
    if (avrsim_open_blank(s, err, err_len)) return -1;
    avr_load_firmware(s->avr, &fw);
    s->avr->sleep = no_wall_sleep;
    return 0;
}

static void push_isr(avrsim_t *s, int vector, avr_cycle_count_t start) {
    if (s->depth > 0) ++s->nested_calls;
    if (s->depth < AVRSIM_MAX_NESTING) {
        avrsim_open_isr_t *o = &s->open[s->depth++];
        o->vector = vector;
        o->start = start;
        o->nested = 0;
    }
}

static void pop_isr(avrsim_t *s) {
    avrsim_open_isr_t o = s->open[--s->depth];
    avr_cycle_count_t total = s->avr->cycle - o.start;
    unsigned long own = (unsigned long)(total - o.nested);
    avrsim_isr_stat_t *st = &s->isr[o.vector & (AVRSIM_VECTORS - 1)];
    ++st->calls;
    st->sum_cycles += (double)own;
    if (own > st->max_cycles) st->max_cycles = own;
    if (s->depth > 0) s->open[s->depth - 1].nested += total;
    s->left = o.vector;
    s->left_cycles = own;
}

int avrsim_step(avrsim_t *s) {
    avr_t *avr = s->avr;
    const avr_flashaddr_t pc0 = avr->pc;
    const int asleep_before = s->asleep;
    const int running_before = avr->state == cpu_Running;
    const uint8_t isr_before = avr->interrupts.running_ptr;
    const uint16_t op = (uint16_t)(avr->flash[pc0] | (avr->flash[pc0 + 1] << 8));
    int executed = 0; /* the instruction at pc0 ran in this step */
    s->entered = s->left = 0;
    s->left_cycles = 0;
    s->pc_before = pc0;
    s->cycle_before = avr->cycle;

    /* correction 3, RETI of an ISR that re-enabled interrupts (ISR_NOBLOCK): SREG.I is already
     * set, so simavr leaves interrupt_state alone and an interrupt raised during the RETI (by a
     * cycle timer) is served in the same step, with no main instruction between. -1 makes
     * simavr's own service routine defer it to after the next instruction. */
    if (running_before && !asleep_before && op == OP_RETI && avr->sreg[S_I] && avr->interrupt_state >= 0)
        avr->interrupt_state = -1;

    if (asleep_before && running_before) {
        /* A stimulus between two steps (avr_raise_irq) woke the core. The hardware vectors
         * first and runs the instruction after SLEEP on return; simavr would run it first. */
        if (avr->sreg[S_I] && avr->interrupt_state > 0) avr_service_interrupts(avr);
        else { avr_run(avr); executed = 1; }
    } else {
        avr_run(avr);
        executed = running_before;
    }

    if (executed && op == OP_SLEEP && avr->state == cpu_Sleeping && !(avr->data[SMCR] & (1u << SE)))
        avr->state = cpu_Running; /* SLEEP with SMCR.SE clear is a NOP on the hardware */

    if (executed && op == OP_RETI && s->depth > 0) pop_isr(s);

    /* correction 3: the instruction that set SREG.I leaves simavr waiting two instructions */
    if (avr->sreg[S_I] && avr->interrupt_state < 0) avr->interrupt_state = (int8_t)avr_has_pending_interrupts(avr);

    /* the core has just vectored (a RETI in the same step has popped one invocation) */
    const int popped = executed && op == OP_RETI && isr_before > 0;
    if (avr->interrupts.running_ptr + popped > isr_before) {
        const int vector = avr->interrupts.running[avr->interrupts.running_ptr - 1]->vector;
        /* hardware sleeps at a SLEEP that simavr skips for a pending interrupt, and wakes at once */
        const int from_sleep = asleep_before || (executed && op == OP_SLEEP && (avr->data[SMCR] & (1u << SE)));
        push_isr(s, vector, avr->cycle);
        avr->cycle += AVRSIM_IRQ_RESPONSE_CYCLES; /* correction 1 */
        if (from_sleep) {
            avr->cycle += AVRSIM_WAKE_CYCLES; /* correction 2 */
            ++s->wakeups;
        }
        s->entered = vector;
    } else if (avr->interrupts.running_ptr < s->depth && avr->interrupts.running_ptr == 0) {
        s->depth = 0; /* a reset abandoned the invocations in progress */
    }
    s->asleep = avr->state == cpu_Sleeping;
    return avr->state;
}

static avr_cycle_count_t stop_here(avr_t *avr, avr_cycle_count_t when, void *param) {
    (void)avr;
    (void)when;
    (void)param;
    return 0;
}

void avrsim_stop_at(avrsim_t *s, avr_cycle_count_t cycle) {
    if (s->avr->cycle < cycle) avr_cycle_timer_register(s->avr, cycle - s->avr->cycle, stop_here, s);
}

void avrsim_run_until(avrsim_t *s, avr_cycle_count_t cycle) {
    avr_t *avr = s->avr;
    avrsim_stop_at(s, cycle);
    while (avr->cycle < cycle && avr->state != cpu_Done && avr->state != cpu_Crashed) avrsim_step(s);
}

void avrsim_clear_isr_stats(avrsim_t *s) {
    memset(s->isr, 0, sizeof s->isr);
    s->nested_calls = 0;
    s->wakeups = 0;
}

void avrsim_abandon_isrs(avrsim_t *s) { s->depth = 0; }

/* ------------------------------------------------------------------------------ ADC */
static avr_cycle_count_t adc_sample_now(avr_t *avr, avr_cycle_count_t when, void *param) {
    (void)avr;
    avrsim_t *s = (avrsim_t *)param;
    if (s->adc_fn && s->adc_channel >= 0) s->adc_fn(s->adc_ctx, s->adc_channel, when);
    return 0;
}

static void adc_started(avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq;
    avrsim_t *s = (avrsim_t *)param;
    union { avr_adc_mux_t mux; uint32_t v; } e;
    e.v = value;
    s->adc_channel = e.mux.kind == ADC_MUX_SINGLE ? (int)e.mux.src : -1;
    ++s->adc_conversions;
    /* ADC clock: the prescaler of ADCSRA's ADPS bits (0 divides by 2, as 1) */
    unsigned adps = s->avr->data[ADCSRA] & 7u;
    avr_cycle_count_t div = 1u << (adps ? adps : 1u);
    avr_cycle_timer_register(s->avr, div * AVRSIM_ADC_SH_CLOCKS_X2 / 2u, adc_sample_now, s);
}

void avrsim_adc_sampler(avrsim_t *s, void (*fn)(void *ctx, int channel, avr_cycle_count_t when), void *ctx) {
    s->adc_fn = fn;
    s->adc_ctx = ctx;
    s->adc_channel = -1;
    s->avr->avcc = 1023u * AVRSIM_ADC_SUBCOUNTS;
    avr_irq_register_notify(avr_io_getirq(s->avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_OUT_TRIGGER), adc_started, s);
}

void avrsim_adc_input(avrsim_t *s, int channel, double vin_over_avcc) {
    double f = vin_over_avcc > 1.0 ? 1.0 : vin_over_avcc > 0.0 ? vin_over_avcc : 0.0; /* NaN -> 0 */
    /* simavr: code = value * 1023 / avcc, truncated; value = (Vin/AVcc 1024 + 0.5) SUB rounds */
    double v = (f * 1024.0 + 0.5) * AVRSIM_ADC_SUBCOUNTS;
    uint32_t value = v > 1023.0 * AVRSIM_ADC_SUBCOUNTS ? 1023u * AVRSIM_ADC_SUBCOUNTS : (uint32_t)v;
    avr_raise_irq(avr_io_getirq(s->avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_ADC0 + channel), value);
}

uint16_t avrsim_rd16(const avrsim_t *s, uint16_t addr) {
    return (uint16_t)(s->avr->data[addr] | (s->avr->data[addr + 1] << 8));
}

double avrsim_seconds(avr_cycle_count_t cycles) { return (double)cycles / (double)AVRSIM_F_CPU_HZ; }

/* ------------------------------------------------------------------------ ELF symbols */
int avrsim_each_symbol(const char *elf_path, avrsim_symbol_fn fn, void *ctx) {
    FILE *f = fopen(elf_path, "rb");
    if (!f) return -1;
    unsigned char *d = NULL;
    size_t len = 0, cap = 0, n;
    unsigned char buf[65536];
    while ((n = fread(buf, 1, sizeof buf, f)) > 0) {
        if (len + n > cap) {
            cap = 2 * (len + n);
            unsigned char *nd = (unsigned char *)realloc(d, cap);
            if (!nd) { free(d); fclose(f); return -1; }
            d = nd;
        }
        memcpy(d + len, buf, n);
        len += n;
    }
    fclose(f);
    Elf32_Ehdr eh;
    if (len < sizeof eh || memcmp(d, ELFMAG, SELFMAG) || d[EI_CLASS] != ELFCLASS32) { free(d); return -1; }
    memcpy(&eh, d, sizeof eh);
    for (int i = 0; i < eh.e_shnum; ++i) {
        Elf32_Shdr sh, st;
        size_t off = eh.e_shoff + (size_t)i * eh.e_shentsize;
        if (off + sizeof sh > len) break;
        memcpy(&sh, d + off, sizeof sh);
        if (sh.sh_type != SHT_SYMTAB) continue;
        size_t stoff = eh.e_shoff + (size_t)sh.sh_link * eh.e_shentsize;
        if (stoff + sizeof st > len) break;
        memcpy(&st, d + stoff, sizeof st);
        for (size_t k = 0; k + sizeof(Elf32_Sym) <= sh.sh_size && sh.sh_offset + k + sizeof(Elf32_Sym) <= len;
             k += sizeof(Elf32_Sym)) {
            Elf32_Sym sym;
            memcpy(&sym, d + sh.sh_offset + k, sizeof sym);
            size_t name_off = st.sh_offset + sym.st_name;
            if (sym.st_name == 0 || name_off >= len || !memchr(d + name_off, 0, len - name_off)) continue;
            fn(sym.st_value, sym.st_size, ELF32_ST_TYPE(sym.st_info) == STT_FUNC, (const char *)(d + name_off), ctx);
        }
    }
    free(d);
    return 0;
}

struct find_ctx { const char *name; long value; };

static void find_one(unsigned long value, unsigned long size, int is_func, const char *name, void *ctx) {
    struct find_ctx *c = (struct find_ctx *)ctx;
    (void)size;
    (void)is_func;
    if (c->value < 0 && strcmp(name, c->name) == 0) c->value = (long)value;
}

long avrsim_symbol(const char *elf_path, const char *name) {
    struct find_ctx c = {name, -1};
    if (avrsim_each_symbol(elf_path, find_one, &c)) return -1;
    return c.value;
}

long avrsim_data_symbol(const char *elf_path, const char *name) {
    long v = avrsim_symbol(elf_path, name);
    return v < 0 ? -1 : (v & 0xFFFF);
}
