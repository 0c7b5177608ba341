#!/usr/bin/env bash
# Builds the two libsimavr harnesses and runs them on a firmware ELF:
#   isr_bench  encoder ISR cycles per edge, edge-rate sweep, max lossless rate, longest I=0
#   fw_smoke   system check over the XBee link (commands, Acks, failsafe, watchdog), task
#              cycles and stack high-water mark as reported by the firmware, cycles per ISR
# Usage: sim/isr_bench/run.sh [firmware.elf] [--profile]
# Default ELF: the PlatformIO build, else the direct avr-g++ build (docs/firmware.md).
set -e
cd "$(dirname "$0")/../.."
. scripts/env.sh  # provisioned avr-gcc, simavr and libsimavr (scripts/setup.sh)
ELF="${1:-}"
if [ -z "$ELF" ]; then
    if [ -f .pio/build/megaatmega2560/firmware.elf ]; then ELF=.pio/build/megaatmega2560/firmware.elf
    else ELF=.build/firmware/firmware.elf; fi
fi
mkdir -p .build
gcc -O2 -Wall -Wextra -o .build/isr_bench sim/isr_bench/isr_bench.c $DD_SIMAVR_CFLAGS $DD_SIMAVR_LIBS
g++ -std=c++14 -O2 -Wall -Wextra -Ilib/protocol/src -o .build/fw_smoke sim/isr_bench/fw_smoke.cpp \
    lib/protocol/src/protocol/*.cpp $DD_SIMAVR_CFLAGS $DD_SIMAVR_LIBS
echo "== $ELF"
avr-size "$ELF"
.build/isr_bench "$ELF"
.build/fw_smoke "$ELF" ${2:-}
