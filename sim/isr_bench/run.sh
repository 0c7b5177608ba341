#!/usr/bin/env bash
# Builds the libsimavr harnesses (host_tools/_build.py) and runs them on a firmware ELF:
#   selftest   sim/common's cycle corrections against the ATmega2560 datasheet
#   isr_bench  encoder ISR cycles per edge, edge-rate sweep, max lossless rate, longest I=0
#   fw_smoke   system check over the XBee link (commands, Acks, failsafe, watchdog), task
#              cycles and stack high-water mark as reported by the firmware, cycles per ISR
# Usage: sim/isr_bench/run.sh [firmware.elf] [--profile]
# Default ELF: the PlatformIO build, else the direct avr-g++ build (docs/firmware.md), else the
# PlatformIO build made now.
set -e
cd "$(dirname "$0")/../.."
ROOT="$PWD"
. scripts/env.sh  # provisioned avr-gcc, simavr, libsimavr, pio
ELF="${1:-}"
if [ -z "$ELF" ]; then
    ELF=.pio/build/megaatmega2560/firmware.elf
    if [ ! -f "$ELF" ]; then
        if [ -f .build/firmware/firmware.elf ]; then ELF=.build/firmware/firmware.elf
        else pio run -e megaatmega2560; fi
    fi
fi
bash sim/common/selftest/run.sh
PYTHONPATH="$ROOT${PYTHONPATH:+:$PYTHONPATH}" "$ROOT/.venv/bin/python" -m host_tools._build isr_bench fw_smoke >/dev/null
echo "== $ELF"
avr-size "$ELF"
.build/isr_bench "$ELF"
.build/fw_smoke "$ELF" ${2:-}
