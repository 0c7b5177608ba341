#!/usr/bin/env bash
# Cycles of the firmware-side traction functions on a simulated ATmega2560 (simavr):
#   bench/plant/avr_cycles.sh
set -e
cd "$(dirname "$0")/../.."
. sim/common/harness.sh  # scripts/env.sh and the libsimavr harness build recipe
mkdir -p .build/bench
avr-g++ -std=gnu++11 -mmcu=atmega2560 -Os -ffunction-sections -fdata-sections -Wl,--gc-sections \
    -fno-exceptions -fno-rtti -Wall -Wextra -Werror -Ilib/slipmodel/src \
    bench/plant/avr_traction.cpp lib/slipmodel/src/slipmodel/traction.cpp -o .build/bench/avr_traction.elf
avr-size .build/bench/avr_traction.elf
harness_build .build/bench/avr_cycles_harness bench/plant/avr_cycles_harness.c
.build/bench/avr_cycles_harness .build/bench/avr_traction.elf
