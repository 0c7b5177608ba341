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
    motor_init();
    cycles_init();
    enc_init();
    xbee_init();
    sei();
    app_init();  // builds the controller configuration (float, ~once): before the schedule starts
    sched_init(app_tasks(), app_task_count());
    wdt_start();
    for (;;) {
        wdt_kick();
        if (!sched_run_one()) {
            app_poll();
            sched_idle();
        }
    }
}
#endif
