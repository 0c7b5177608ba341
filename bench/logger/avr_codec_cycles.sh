#!/usr/bin/env bash
# Build bench/logger/avr_codec_cycles.cpp with avr-g++ 5.4 (-Os) and run it in simavr.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
source "$ROOT/scripts/env.sh"  # provisioned avr-gcc and simavr (scripts/setup.sh)
OUT="$ROOT/.build/bench"
mkdir -p "$OUT"
F="-mmcu=atmega2560 -Os -std=gnu++11 -fno-exceptions -fno-rtti -Wall -Wextra -DF_CPU=16000000UL -I$ROOT/lib/protocol/src"
avr-g++ $F "$ROOT/bench/logger/avr_codec_cycles.cpp" "$ROOT"/lib/protocol/src/protocol/*.cpp -o "$OUT/avr_codec_cycles.elf"
avr-size "$OUT/avr_codec_cycles.elf"
simavr -m atmega2560 -f 16000000 "$OUT/avr_codec_cycles.elf" 2>&1 | sed -e 's/\x1b\[[0-9;]*m//g' | grep -v '^Loaded'
