#include "boot.h"

#include <avr/eeprom.h>
#include <avr/io.h>
#include <avr/wdt.h>

#include "board.h"

namespace {
const uint8_t kPaint = 0xC5;
const uint8_t kStopRun = 8;  // consecutive paint bytes that end the scan
}  // namespace

extern "C" {
extern uint8_t __heap_start;  // end of .data/.bss/.noinit (linker)
uint8_t g_boot_mcusr __attribute__((section(".noinit")));
uint8_t* g_stack_low __attribute__((section(".noinit")));
void boot_early() __attribute__((naked, used, section(".init3")));
}

void boot_early() {
    // Motor Shield pins safe (board.h): PWM outputs low, DIR low, BRAKE high.
    MOTOR_R_PWM_PORT &= static_cast<uint8_t>(~_BV(MOTOR_R_PWM_BIT));
    MOTOR_R_PWM_DDR |= _BV(MOTOR_R_PWM_BIT);
    MOTOR_L_PWM_PORT &= static_cast<uint8_t>(~_BV(MOTOR_L_PWM_BIT));
    MOTOR_L_PWM_DDR |= _BV(MOTOR_L_PWM_BIT);
    MOTOR_DIR_PORT &= static_cast<uint8_t>(~MOTOR_DIR_MASK);
    MOTOR_DIR_DDR |= MOTOR_DIR_MASK;
    MOTOR_BRAKE_PORT |= MOTOR_BRAKE_MASK;
    MOTOR_BRAKE_DDR |= MOTOR_BRAKE_MASK;
    g_boot_mcusr = MCUSR;
    MCUSR = 0;
    wdt_disable();
    // Paint [__heap_start, SP]: SP = RAMEND here, nothing is on the stack yet.
    uint8_t* p = &__heap_start;
    uint8_t* top = reinterpret_cast<uint8_t*>(SP);
    while (p <= top) *p++ = kPaint;
    g_stack_low = top;  // nothing used yet
}

uint8_t boot_reset_cause() { return g_boot_mcusr; }

namespace {
uint16_t g_boot_count;
}  // namespace

void boot_count_init() {
    uint16_t* addr = reinterpret_cast<uint16_t*>(kBootCountEeprom);
    g_boot_count = static_cast<uint16_t>(eeprom_read_word(addr) + 1u);
    eeprom_update_word(addr, g_boot_count);
}

uint16_t boot_count() { return g_boot_count; }

void wdt_start() { wdt_enable(WDTO_250MS); }
void wdt_kick() { wdt_reset(); }

uint16_t stack_high_water(uint16_t max_bytes) {
    uint8_t* low = g_stack_low;
    uint8_t* p = low;
    uint8_t run = 0;
    uint16_t n = 0;
    while (p > &__heap_start && run < kStopRun && (max_bytes == 0 || n++ < max_bytes)) {
        --p;
        if (*p != kPaint) {
            low = p;
            run = 0;
        } else {
            ++run;
        }
    }
    g_stack_low = low;
    return static_cast<uint16_t>(static_cast<uint16_t>(RAMEND) - reinterpret_cast<uint16_t>(low) + 1u);
}

uint16_t stack_region_bytes() {
    return static_cast<uint16_t>(RAMEND + 1u - reinterpret_cast<uint16_t>(&__heap_start));
}
