#!/usr/bin/env bash
# Cycles of the firmware-side traction functions on a simulated ATmega2560 (simavr):
#   bench/plant/avr_cycles.sh
set -e
cd "$(dirname "$0")/../.."
ROOT="$PWD"
. scripts/env.sh  # the provisioned avr-gcc and libsimavr
mkdir -p .build/bench
avr-g++ -std=gnu++11 -mmcu=atmega2560 -Os -ffunction-sections -fdata-sections -Wl,--gc-sections \
    -fno-exceptions -fno-rtti -Wall -Wextra -Werror -Ilib/slipmodel/src \
    bench/plant/avr_traction.cpp lib/slipmodel/src/slipmodel/traction.cpp -o .build/bench/avr_traction.elf
avr-size .build/bench/avr_traction.elf
PYTHONPATH="$ROOT${PYTHONPATH:+:$PYTHONPATH}" "$ROOT/.venv/bin/python" -m host_tools._build avr_cycles_harness >/dev/null
.build/bench/avr_cycles_harness .build/bench/avr_traction.elf
