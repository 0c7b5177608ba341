#!/bin/sh
# Build the lib/control AVR cycle benchmark the way the firmware is built and run it in simavr.
# Usage (from anywhere): sh bench/control_avr/run.sh      Output: a table of CPU cycles.
set -eu
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
OUT="$ROOT/.build/bench_control_avr"
mkdir -p "$OUT"
avr-g++ -std=gnu++11 -Os -mmcu=atmega2560 -DF_CPU=16000000UL -Wall -Wextra \
  -fno-exceptions -fno-rtti -ffunction-sections -fdata-sections -Wl,--gc-sections \
  -I"$ROOT/lib/control/src" -I"$ROOT/lib/slipmodel/src" \
  "$ROOT/bench/control_avr/bench.cpp" "$ROOT"/lib/control/src/control/*.cpp \
  "$ROOT"/lib/slipmodel/src/slipmodel/*.cpp -lm -o "$OUT/bench.elf"
avr-size "$OUT/bench.elf" | sed 's/^/# /'
# simavr prints UART0 lines itself (coloured); strip the escape codes and keep our table.
simavr -m atmega2560 -f 16000000 "$OUT/bench.elf" 2>&1 \
  | sed -e 's/\x1b\[[0-9;]*m//g' -e 's/\.$//' \
  | sed -n '/^BEGIN control_avr/,/^END/p'
