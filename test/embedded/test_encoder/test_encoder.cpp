// Encoder ISR decoding on the (simulated) ATmega2560: all 16 transitions of each wheel, both
// wheels at once, the rare 16-bit carry paths and the 32-bit extension in enc_snapshot().
// The pins PD0..PD3 are switched to outputs so that writing PORTD produces real pin changes:
// INT0..INT3 fire on output pins too (datasheet "software interrupt"), running the real ISRs.
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <stdio.h>
#include <unity.h>

#include "board.h"
#include "encoder.h"

namespace {

// Expected outcome of prev -> cur for a wheel whose forward sequence is A leading B,
// (B,A) = 00 -> 01 -> 11 -> 10 -> 00. Written out by hand from that sequence (not computed
// like the ISR's table): 0 none, +1 forward, -1 backward, 2 illegal (both channels changed).
const int8_t kExpect[4][4] = {
    //          cur: 00  01  10  11      (state = B << 1 | A)
    /* 00 */ {0, +1, -1, 2},
    /* 01 */ {-1, 0, 2, +1},
    /* 10 */ {+1, 2, 0, -1},
    /* 11 */ {2, -1, +1, 0},
};

void settle() {
    // the ISR needs ~40 cycles; give pending interrupts time to run
    for (volatile uint8_t i = 0; i < 20; ++i) {
    }
}

void set_pins(uint8_t low_nibble) {
    PORTD = static_cast<uint8_t>((PORTD & 0xF0) | (low_nibble & 0x0F));
    settle();
}

uint8_t left_bits(uint8_t s) { return s & 3; }              // A = PD0, B = PD1
uint8_t right_bits(uint8_t s) { return (s & 3) << 2; }      // A = PD2, B = PD3

void check_wheel(bool left) {
    const int8_t sign = left ? (ENC_LEFT_REVERSED ? -1 : 1) : (ENC_RIGHT_REVERSED ? -1 : 1);
    for (uint8_t prev = 0; prev < 4; ++prev) {
        for (uint8_t cur = 0; cur < 4; ++cur) {
            uint8_t other = static_cast<uint8_t>(PIND & (left ? 0x0C : 0x03));
            set_pins(static_cast<uint8_t>(other | (left ? left_bits(prev) : right_bits(prev))));
            EncRaw a = enc_read_raw();
            set_pins(static_cast<uint8_t>(other | (left ? left_bits(cur) : right_bits(cur))));
            EncRaw b = enc_read_raw();
            int16_t dpos = static_cast<int16_t>(left ? b.pos_l - a.pos_l : b.pos_r - a.pos_r);
            uint16_t dill = static_cast<uint16_t>(left ? b.ill_l - a.ill_l : b.ill_r - a.ill_r);
            int16_t dother = static_cast<int16_t>(left ? b.pos_r - a.pos_r : b.pos_l - a.pos_l);
            int8_t e = kExpect[prev][cur];
            char msg[40];
            snprintf(msg, sizeof msg, "%s prev %u cur %u", left ? "left" : "right", prev, cur);
            if (e == 2) {
                TEST_ASSERT_EQUAL_INT16_MESSAGE(0, dpos, msg);
                TEST_ASSERT_EQUAL_UINT16_MESSAGE(1, dill, msg);
            } else {
                TEST_ASSERT_EQUAL_INT16_MESSAGE(sign * e, dpos, msg);
                TEST_ASSERT_EQUAL_UINT16_MESSAGE(0, dill, msg);
            }
            TEST_ASSERT_EQUAL_INT16_MESSAGE(0, dother, msg);  // the other wheel is untouched
        }
    }
}

void write_raw(volatile uint16_t* p, uint16_t v) {
    cli();
    *p = v;
    sei();
}

}  // namespace

void setUp() {
    set_pins(0);
    enc_init();
    DDRD |= 0x0F;  // drive our own encoder pins
    sei();
}
void tearDown() { DDRD &= static_cast<uint8_t>(~0x0F); }

static void test_left_all_16_transitions() { check_wheel(true); }
static void test_right_all_16_transitions() { check_wheel(false); }

static void test_both_wheels_change_at_once() {
    set_pins(0);
    EncRaw a = enc_read_raw();
    set_pins(static_cast<uint8_t>(left_bits(1) | right_bits(1)));  // 00 -> 01 on both
    EncRaw b = enc_read_raw();
    TEST_ASSERT_EQUAL_INT16((ENC_LEFT_REVERSED ? -1 : 1), static_cast<int16_t>(b.pos_l - a.pos_l));
    TEST_ASSERT_EQUAL_INT16((ENC_RIGHT_REVERSED ? -1 : 1), static_cast<int16_t>(b.pos_r - a.pos_r));
    TEST_ASSERT_EQUAL_UINT16(0, b.ill_l - a.ill_l);
    TEST_ASSERT_EQUAL_UINT16(0, b.ill_r - a.ill_r);
}

// One forward step of the right wheel (A leads B unless reversed).
static void right_step(bool forward) {
    static const uint8_t seq[4] = {0, 1, 3, 2};
    uint8_t s = (PIND >> 2) & 3;
    uint8_t i = 0;
    while (seq[i] != s) ++i;
    bool up = forward != (ENC_RIGHT_REVERSED != 0);
    set_pins(static_cast<uint8_t>((PIND & 0x03) | right_bits(seq[(i + (up ? 1 : 3)) & 3])));
}

static void test_carry_into_high_byte() {
    write_raw(&enc_raw_r, 0x00FF);
    right_step(true);
    TEST_ASSERT_EQUAL_HEX16(0x0100, enc_read_raw().pos_r);
    right_step(false);
    TEST_ASSERT_EQUAL_HEX16(0x00FF, enc_read_raw().pos_r);
    write_raw(&enc_raw_r, 0x0000);
    right_step(false);
    TEST_ASSERT_EQUAL_HEX16(0xFFFF, enc_read_raw().pos_r);
    right_step(true);
    TEST_ASSERT_EQUAL_HEX16(0x0000, enc_read_raw().pos_r);
}

static void test_illegal_counter_carry() {
    write_raw(&enc_ill_r, 0x00FF);
    uint8_t s = (PIND >> 2) & 3;
    set_pins(static_cast<uint8_t>((PIND & 0x03) | right_bits(s ^ 3)));  // both channels flip
    TEST_ASSERT_EQUAL_HEX16(0x0100, enc_read_raw().ill_r);
}

static void test_snapshot_extends_to_32_bits() {
    EncSnapshot s0 = enc_snapshot();
    TEST_ASSERT_EQUAL_INT32(0, s0.count_l);
    uint16_t raw = enc_read_raw().pos_l;
    for (uint8_t i = 0; i < 3; ++i) {  // three jumps of +30000: past 2^16
        raw = static_cast<uint16_t>(raw + 30000u);
        write_raw(&enc_raw_l, raw);
        enc_snapshot();
    }
    TEST_ASSERT_EQUAL_INT32(90000L, enc_snapshot().count_l);
    for (uint8_t i = 0; i < 6; ++i) {  // and back below zero
        raw = static_cast<uint16_t>(raw - 30000u);
        write_raw(&enc_raw_l, raw);
        enc_snapshot();
    }
    TEST_ASSERT_EQUAL_INT32(-90000L, enc_snapshot().count_l);
}

int main() {
    UNITY_BEGIN();
    RUN_TEST(test_left_all_16_transitions);
    RUN_TEST(test_right_all_16_transitions);
    RUN_TEST(test_both_wheels_change_at_once);
    RUN_TEST(test_carry_into_high_byte);
    RUN_TEST(test_illegal_counter_carry);
    RUN_TEST(test_snapshot_extends_to_32_bits);
    UNITY_END();
    cli();
    sleep_cpu();
    return 0;
}
