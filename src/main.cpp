// Firmware entry point (bare-metal avr-libc). See docs/firmware.md.
#include <avr/interrupt.h>

#include "app.h"
#include "boot.h"
#include "cycles.h"
#include "encoder.h"
#include "motor.h"
#include "sched.h"
#include "xbee.h"

#ifndef PIO_UNIT_TESTING
int main() {
    // boot.cpp (.init3) has already made the motor pins safe, saved MCUSR, stopped the WDT.
    boot_count_init();
    motor_init();
    cycles_init();
    enc_init();
    xbee_init();
    sei();
    app_init();  // builds the controller configuration (float, ~once): before the schedule starts
    sched_init(app_tasks(), app_task_count());
    wdt_start();
    uint32_t kicked_ms = sched_ms();
    for (;;) {
        // Kick only while the 1 kHz tick advances: a hung task, a hung main loop or a dead
        // tick (no task would ever run again) all end in a watchdog reset within 250 ms.
        uint32_t now_ms = sched_ms();
        if (now_ms != kicked_ms) {
            wdt_kick();
            kicked_ms = now_ms;
        }
        if (!sched_run_one()) {
            app_poll();
            sched_idle();
        }
    }
}
#endif
