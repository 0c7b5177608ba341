// Quadrature encoder driver: INT0..INT3 on PD0..PD3, 4x decoding in hand-written ISRs
// (src/encoder_isr.S), 16-bit counters in the ISR extended to 32 bits by enc_snapshot().
#ifndef FW_ENCODER_H
#define FW_ENCODER_H

#include <stdint.h>

extern "C" {
// Written only by the ISRs; read only through enc_snapshot() / enc_read_raw().
extern volatile uint16_t enc_raw_l, enc_raw_r;  // position, mod 2^16
extern volatile uint16_t enc_ill_l, enc_ill_r;  // illegal transitions, mod 2^16
}

struct EncSnapshot {
    int32_t count_l;       // cumulative counts, positive = forward, saturating
    int32_t count_r;
    uint32_t illegal_l;    // cumulative illegal transitions (both channels changed at once)
    uint32_t illegal_r;
};

struct EncRaw {
    uint16_t pos_l, pos_r, ill_l, ill_r;
};

// Configures INT0..INT3 for any-edge, pull-ups on, seeds the previous state, clears counters.
void enc_init();
// Atomic copy of the four ISR counters (interrupts off for ~20 cycles).
EncRaw enc_read_raw();
// Extends the ISR counters to 32 bits and returns the totals. Must be called at least every
// 90 ms (32767 counts at the ISR's maximum rate of 363k edges/s); the scheduler calls it every
// 20 ms. Main-loop context only (not reentrant).
EncSnapshot enc_snapshot();

#endif  // FW_ENCODER_H
