// Firmware entry point (bare-metal avr-libc). Grows with the drivers; see docs/firmware.md.
#include <avr/interrupt.h>

#include "encoder.h"

#ifndef PIO_UNIT_TESTING
int main() {
    enc_init();
    sei();
    for (;;) {
        (void)enc_snapshot();
    }
}
#endif
