#include "cycles.h"

#include <avr/interrupt.h>
#include <avr/io.h>

#include "board.h"

static_assert(F_CPU == 16000000UL, "time_us() divides cycles by 16");

namespace {
volatile uint32_t g_t5_ovf;  // cycle-clock timer overflows (one per 65536 cycles = 4.096 ms)

// Consistent (overflow count, counter) pair; interrupts must be off.
inline void read_pair(uint32_t* ovf, uint16_t* cnt) {
    uint16_t c = CYCLES_TCNT;
    uint32_t o = g_t5_ovf;
    // An overflow that happened since the last ISR but before the read: count it here.
    if ((CYCLES_TIFR & _BV(CYCLES_TOV)) && c < 0x8000u) ++o;
    *ovf = o;
    *cnt = c;
}
}  // namespace

// NOBLOCK: encoder edges may interrupt this ISR (the overflow flag is cleared on entry).
// read_pair() runs with interrupts off, so it never sees a half-updated count.
ISR(CYCLES_OVF_VECT, ISR_NOBLOCK) { g_t5_ovf = g_t5_ovf + 1; }

void cycles_init() {
    CYCLES_TCCRA = 0;
    CYCLES_TCCRB = CYCLES_TCCRB_RUN;  // normal mode, clk/1
    CYCLES_TCNT = 0;
    CYCLES_TIFR = _BV(CYCLES_TOV);
    CYCLES_TIMSK = _BV(CYCLES_TOIE);
}

uint32_t cycles_now() {
    uint8_t sreg = SREG;
    cli();
    uint32_t o;
    uint16_t c;
    read_pair(&o, &c);
    SREG = sreg;
    return (o << 16) | c;
}

uint32_t time_us() {
    uint8_t sreg = SREG;
    cli();
    uint32_t o;
    uint16_t c;
    read_pair(&o, &c);
    SREG = sreg;
    // cycles / 16 for a 48-bit cycle count, kept to 32 bits: (o * 65536 + c) / 16
    return (o << 12) | (c >> 4);
}
