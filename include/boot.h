// Reset handling, watchdog and stack monitoring.
// Before main() (.init3, right after avr-libc has set up SP and r1):
//   - the motor pins are driven safe: PWM outputs low (L298 disabled), brake pins high,
//     direction low -- the motors are off from the first microseconds and stay off until a
//     Start command;
//   - MCUSR is saved (boot_reset_cause()) and cleared, and the watchdog is disabled (after a
//     watchdog reset it would otherwise stay enabled at 15 ms and reset the board in a loop);
//   - the free RAM between the end of .bss/.noinit and the top of the stack is painted.
#ifndef FW_BOOT_H
#define FW_BOOT_H

#include <stdint.h>

// MCUSR as read at reset: bit 0 PORF, 1 EXTRF, 2 BORF, 3 WDRF, 4 JTRF (== protocol reset_cause).
uint8_t boot_reset_cause();

// Boot counter (telemetry boot_count): EEPROM word kBootCountEeprom, read, incremented and
// written back once per boot by boot_count_init() (from main(), before the schedule: the
// EEPROM write takes about 7 ms). An erased EEPROM (0xFFFF) makes the first boot 0. The host
// recognises a reset by a change of this number, not by the clock or seq restarting.
const uint16_t kBootCountEeprom = 0;
void boot_count_init();
uint16_t boot_count();

// Watchdog: 250 ms; wdt_kick() from the main loop only.
void wdt_start();
void wdt_kick();

// Largest stack depth seen so far, in bytes (scans downward from the previous low-water
// mark; cost proportional to the growth since the last call, at most max_bytes bytes of it per
// call: 0 = no limit, and a bounded call that stops early goes on from there the next time).
uint16_t stack_high_water(uint16_t max_bytes = 0);
// Bytes between the end of static data and the top of RAM (stack + free).
uint16_t stack_region_bytes();

#endif  // FW_BOOT_H
