// Watchdog-reset path on the (simulated) ATmega2560. The program boots twice:
//   1st boot (no WDRF in the saved MCUSR): start the firmware's watchdog and hang, as a hung
//      main loop would. Nothing is printed.
//   2nd boot (after the watchdog reset): Unity checks what src/boot.cpp did before main():
//      reset cause saved with WDRF, MCUSR cleared, watchdog disabled (no reset loop), motor
//      pins safe (PWM low, brake high), and the stack painted (high-water mark measurable).
// If the watchdog never fires, the program hangs and the runner's timeout reports it.
#include <avr/interrupt.h>
#include <avr/io.h>
#include <avr/sleep.h>
#include <avr/wdt.h>
#include <unity.h>

#include "boot.h"

void setUp() {}
void tearDown() {}

static void test_reset_cause_is_watchdog() {
    TEST_ASSERT_BITS_HIGH(_BV(WDRF), boot_reset_cause());
    TEST_ASSERT_EQUAL_HEX8(0, MCUSR);  // cleared at boot, so the next cause is not mixed in
}

static void test_watchdog_disabled_after_reset() {
    TEST_ASSERT_BITS_LOW(_BV(WDE) | _BV(WDIE), WDTCSR);
}

static void test_motor_pins_safe_before_main() {
    // PWM D3 = PE5 and D11 = PB5: outputs, low (L298 disabled)
    TEST_ASSERT_BITS_HIGH(_BV(PE5), DDRE);
    TEST_ASSERT_BITS_LOW(_BV(PE5), PORTE);
    TEST_ASSERT_BITS_HIGH(_BV(PB5), DDRB);
    TEST_ASSERT_BITS_LOW(_BV(PB5), PORTB);
    // BRAKE D9 = PH6 and D8 = PH5: outputs, high
    TEST_ASSERT_BITS_HIGH(_BV(PH5) | _BV(PH6), DDRH);
    TEST_ASSERT_BITS_HIGH(_BV(PH5) | _BV(PH6), PORTH);
}

static uint16_t deep(uint8_t n) {
    volatile uint8_t pad[16];
    for (uint8_t i = 0; i < sizeof pad; ++i) pad[i] = static_cast<uint8_t>(i + n);
    return n == 0 ? pad[3] : static_cast<uint16_t>(pad[5] + deep(static_cast<uint8_t>(n - 1)));
}

static void test_stack_high_water_sees_a_deeper_call() {
    uint16_t before = stack_high_water();
    TEST_ASSERT_TRUE(before > 0 && before < stack_region_bytes());
    volatile uint16_t r = deep(20);  // > 20 frames of >= 18 bytes
    (void)r;
    uint16_t after = stack_high_water();
    TEST_ASSERT_TRUE(after >= before + 300);
    TEST_ASSERT_TRUE(after < stack_region_bytes());
}

int main() {
    if (!(boot_reset_cause() & _BV(WDRF))) {
        wdt_start();
        sei();
        for (;;) {  // a hung main loop: no wdt_kick()
        }
    }
    UNITY_BEGIN();
    RUN_TEST(test_reset_cause_is_watchdog);
    RUN_TEST(test_watchdog_disabled_after_reset);
    RUN_TEST(test_motor_pins_safe_before_main);
    RUN_TEST(test_stack_high_water_sees_a_deeper_call);
    UNITY_END();
    cli();
    sleep_cpu();
    return 0;
}
