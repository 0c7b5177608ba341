// Motor Shield R3 driver on the (simulated) ATmega2560: timer setup (fast PWM, 20 kHz),
// duty -> compare value and direction pin per wheel, duty 0 = output disconnected and low,
// brake, the duty ramp, and the current-sense conversion sequence A0 then A1.
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <stdio.h>
#include <unity.h>

#include "board.h"
#include "motor.h"

void setUp() {
    motor_init();
    sei();
}
void tearDown() {}

static void test_init_leaves_motors_off_and_braked() {
    TEST_ASSERT_BITS_HIGH(_BV(PH5) | _BV(PH6), PORTH);  // brake
    TEST_ASSERT_BITS_LOW(_BV(PE5), PORTE);
    TEST_ASSERT_BITS_LOW(_BV(PB5), PORTB);
    TEST_ASSERT_BITS_LOW(_BV(COM3C1) | _BV(COM3C0), TCCR3A);  // outputs disconnected
    TEST_ASSERT_BITS_LOW(_BV(COM1A1) | _BV(COM1A0), TCCR1A);
    TEST_ASSERT_TRUE(motor_braking());
}

static void test_fast_pwm_20khz() {
    // WGM 14 (fast PWM, TOP = ICRn) and clk/1 on both timers: 16 MHz / (799 + 1) = 20 kHz
    TEST_ASSERT_EQUAL_HEX8(_BV(WGM31), TCCR3A & (_BV(WGM31) | _BV(WGM30)));
    TEST_ASSERT_EQUAL_HEX8(_BV(WGM33) | _BV(WGM32) | _BV(CS30), TCCR3B);
    TEST_ASSERT_EQUAL_HEX8(_BV(WGM11), TCCR1A & (_BV(WGM11) | _BV(WGM10)));
    TEST_ASSERT_EQUAL_HEX8(_BV(WGM13) | _BV(WGM12) | _BV(CS10), TCCR1B);
    TEST_ASSERT_EQUAL_UINT16(799, ICR3);
    TEST_ASSERT_EQUAL_UINT16(799, ICR1);
    uint16_t hi = 0;
    for (uint16_t i = 0; i < 3000; ++i) {  // the counter wraps at TOP
        uint16_t t = TCNT3;
        TEST_ASSERT_TRUE(t <= 799);
        if (t > hi) hi = t;
    }
    char msg[48];
    snprintf(msg, sizeof msg, "highest TCNT3 seen %u", hi);
    TEST_ASSERT_TRUE_MESSAGE(hi > 700, msg);
}

static void test_duty_to_compare_and_direction() {
    motor_set_q15(kRight, 16384);  // +0.5
    TEST_ASSERT_FALSE(motor_braking());
    TEST_ASSERT_BITS_LOW(_BV(PH5) | _BV(PH6), PORTH);  // brake released
    TEST_ASSERT_EQUAL_UINT16(400, motor_compare(kRight));  // 400 of 800 counts high
    TEST_ASSERT_EQUAL_UINT16(399, OCR3C);                  // fast PWM: high for OCR + 1 counts
    TEST_ASSERT_BITS_HIGH(_BV(COM3C1), TCCR3A);
    TEST_ASSERT_EQUAL(MOTOR_RIGHT_DIR_FORWARD_LEVEL ? 1 : 0, (PORTB >> PB6) & 1);
    TEST_ASSERT_EQUAL_UINT16(0, motor_compare(kLeft));  // the other wheel stays off

    motor_set_q15(kLeft, -8192);  // -0.25: backward
    TEST_ASSERT_EQUAL_UINT16(200, motor_compare(kLeft));
    TEST_ASSERT_EQUAL_UINT16(199, OCR1A);
    TEST_ASSERT_BITS_HIGH(_BV(COM1A1), TCCR1A);
    TEST_ASSERT_EQUAL(MOTOR_LEFT_DIR_FORWARD_LEVEL ? 0 : 1, (PORTB >> PB7) & 1);
    TEST_ASSERT_EQUAL_INT16(-8192, motor_duty_q15(kLeft));

    motor_set_q15(kRight, -32768);  // -1: 100 % (OCR = TOP: output constantly high)
    TEST_ASSERT_EQUAL_UINT16(800, motor_compare(kRight));
    TEST_ASSERT_EQUAL_UINT16(799, OCR3C);
    motor_set_q15(kRight, 1);  // rounds to 0: disconnected, pin low (no 1-clock spikes)
    TEST_ASSERT_EQUAL_UINT16(0, motor_compare(kRight));
    TEST_ASSERT_BITS_LOW(_BV(COM3C1) | _BV(COM3C0), TCCR3A);
    TEST_ASSERT_BITS_LOW(_BV(PE5), PORTE);
}

static void test_brake_shorts_both_motors() {
    motor_set_q15(kRight, 10000);
    motor_set_q15(kLeft, 10000);
    motor_brake();
    TEST_ASSERT_TRUE(motor_braking());
    TEST_ASSERT_BITS_HIGH(_BV(PH5) | _BV(PH6), PORTH);
    TEST_ASSERT_EQUAL_UINT16(800, motor_compare(kRight));  // enable high
    TEST_ASSERT_EQUAL_UINT16(800, motor_compare(kLeft));
    TEST_ASSERT_EQUAL_INT16(0, motor_duty_q15(kRight));
    TEST_ASSERT_EQUAL_INT16(0, motor_duty_q15(kLeft));
}

// The duty ramp of the torque->PWM map: each tick adds the slope, at most `steps` times, and
// saturates; the brake ends it and a tick leaves the braked motors alone.
static void test_duty_ramp() {
    motor_set_ramp_q15(10000, 100, -10000, -50, 3);
    for (uint8_t i = 0; i < 5; ++i) motor_ramp_tick();
    TEST_ASSERT_EQUAL_INT16(10300, motor_duty_q15(kRight));
    TEST_ASSERT_EQUAL_INT16(-10150, motor_duty_q15(kLeft));
    TEST_ASSERT_EQUAL_UINT16((800ul * 10300 + 16384) >> 15, motor_compare(kRight));
    motor_set_ramp_q15(32700, 100, 0, 0, 24);
    motor_ramp_tick();
    TEST_ASSERT_EQUAL_INT16(32767, motor_duty_q15(kRight));
    motor_set_ramp_q15(1000, 10, 1000, 10, 24);
    motor_brake();
    motor_ramp_tick();
    TEST_ASSERT_TRUE(motor_braking());
    TEST_ASSERT_EQUAL_INT16(0, motor_duty_q15(kRight));
    TEST_ASSERT_EQUAL_UINT16(800, motor_compare(kRight));
}

static void test_current_sense_converts_a0_then_a1() {
    motor_sense_start();
    TEST_ASSERT_EQUAL_HEX8(0, ADMUX & 0x1F);  // A0 first
    for (volatile uint16_t i = 0; i < 2000; ++i) {  // 2 x 104 us at 125 kHz ADC clock
    }
    TEST_ASSERT_BITS_LOW(_BV(ADSC), ADCSRA);  // both conversions done
    TEST_ASSERT_EQUAL_HEX8(1, ADMUX & 0x1F);  // then A1
    TEST_ASSERT_TRUE(motor_sense_raw(kRight) <= 1023 && motor_sense_raw(kLeft) <= 1023);
}

int main() {
    UNITY_BEGIN();
    RUN_TEST(test_init_leaves_motors_off_and_braked);
    RUN_TEST(test_fast_pwm_20khz);
    RUN_TEST(test_duty_to_compare_and_direction);
    RUN_TEST(test_brake_shorts_both_motors);
    RUN_TEST(test_duty_ramp);
    RUN_TEST(test_current_sense_converts_a0_then_a1);
    UNITY_END();
    cli();
    sleep_cpu();
    return 0;
}
