// Free-running time base: Timer5 at F_CPU (prescaler 1), extended by its overflow interrupt.
// cycles_now() measures execution time in CPU cycles (wraps every 268 s, differences are
// exact); time_us() is board time in microseconds (wraps after 4295 s).
#ifndef FW_CYCLES_H
#define FW_CYCLES_H

#include <stdint.h>

void cycles_init();
uint32_t cycles_now();
uint32_t time_us();

#endif  // FW_CYCLES_H
