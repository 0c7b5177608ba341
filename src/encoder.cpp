#include "encoder.h"

#include <avr/interrupt.h>
#include <avr/io.h>
#include "board.h"  // pins, interrupts, ISR state registers; F_CPU for util/delay.h
#include <util/delay.h>

namespace {
EncRaw g_last;          // raw values at the previous snapshot
EncSnapshot g_total;    // extended totals

int32_t add_sat_i32(int32_t a, int16_t d) {
    if (d > 0 && a > static_cast<int32_t>(0x7FFFFFFFL) - d) return 0x7FFFFFFFL;
    if (d < 0 && a < static_cast<int32_t>(-0x7FFFFFFFL - 1) - d) return -0x7FFFFFFFL - 1;
    return a + d;
}
uint32_t add_sat_u32(uint32_t a, uint16_t d) {
    return (a > 0xFFFFFFFFul - d) ? 0xFFFFFFFFul : a + d;
}
}  // namespace

void enc_init() {
    uint8_t sreg = SREG;
    cli();
    ENC_DDR &= static_cast<uint8_t>(~ENC_MASK);
    ENC_PORT |= ENC_MASK;               // pull-ups (open-collector encoders read high when idle)
    _delay_us(20);                      // let the lines settle before the first sample
    // ISCn = 01: any logical change, for the encoders' INT0..INT3.
    EICRA = ENC_EICRA_ANY_CHANGE;
    // INT4..INT7 are not used (their interrupts stay disabled). Their sense is set to "any
    // change" instead of the reset value "low level": simavr 1.6 polls a level-sensing pin on
    // every cycle even when the interrupt is masked, and INT5's pin PE5 is the right motor's
    // PWM output -- a 5-10x slower simulation (docs/fil.md). No effect on the hardware.
    EICRB = _BV(ISC40) | _BV(ISC50) | _BV(ISC60) | _BV(ISC70);
    enc_raw_l = enc_raw_r = 0;
    enc_ill_l = enc_ill_r = 0;
    g_last = EncRaw{0, 0, 0, 0};
    g_total = EncSnapshot{0, 0, 0, 0};
    // Clear the flags BEFORE sampling the pins: an edge after the sample stays flagged and is
    // decoded against the sampled state as soon as the interrupts are enabled.
    EIFR = ENC_INT_MASK;
    uint8_t pins = ENC_PIN;
    ENC_PREV_L_GPIOR = pins & ENC_LEFT_MASK;   // previous states, see src/encoder_isr.S
    ENC_PREV_R_GPIOR = pins & ENC_RIGHT_MASK;
    EIMSK |= ENC_INT_MASK;
    SREG = sreg;
}

EncRaw enc_read_raw() {
    EncRaw r;
    uint8_t sreg = SREG;
    cli();
    r.pos_l = enc_raw_l;
    r.pos_r = enc_raw_r;
    r.ill_l = enc_ill_l;
    r.ill_r = enc_ill_r;
    SREG = sreg;
    return r;
}

EncSnapshot enc_snapshot() {
    EncRaw r = enc_read_raw();
    g_total.count_l = add_sat_i32(g_total.count_l, static_cast<int16_t>(r.pos_l - g_last.pos_l));
    g_total.count_r = add_sat_i32(g_total.count_r, static_cast<int16_t>(r.pos_r - g_last.pos_r));
    g_total.illegal_l = add_sat_u32(g_total.illegal_l, static_cast<uint16_t>(r.ill_l - g_last.ill_l));
    g_total.illegal_r = add_sat_u32(g_total.illegal_r, static_cast<uint16_t>(r.ill_r - g_last.ill_r));
    g_last = r;
    return g_total;
}
