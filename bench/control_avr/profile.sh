#!/usr/bin/env bash
# Cycle profile of the control benchmark per function (and per source line where the line
# is not an inlined helper): builds bench.cpp with -g (same code as run.sh), runs it under the
# libsimavr harness profile.c, and maps the cycles per program address to functions/lines.
# Usage: bash bench/control_avr/profile.sh [function-name-substring ...]
set -eu
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
. "$ROOT/scripts/env.sh"  # the provisioned avr-gcc and libsimavr
OUT="$ROOT/.build/bench_control_avr"
mkdir -p "$OUT"
PYTHONPATH="$ROOT${PYTHONPATH:+:$PYTHONPATH}" "$ROOT/.venv/bin/python" -m host_tools._build control_profile >/dev/null
avr-g++ -g -DCTL_PROFILE -std=gnu++11 -Os -mmcu=atmega2560 -DF_CPU=16000000UL -Wall -Wextra \
  -fno-exceptions -fno-rtti -ffunction-sections -fdata-sections -Wl,--gc-sections \
  -I"$ROOT/lib/control/src" -I"$ROOT/lib/slipmodel/src" \
  "$ROOT/bench/control_avr/bench.cpp" "$ROOT"/lib/control/src/control/*.cpp \
  "$ROOT"/lib/slipmodel/src/slipmodel/*.cpp -lm -o "$OUT/bench_g.elf"
"$OUT/profile" "$OUT/bench_g.elf" > "$OUT/pcs.txt" 2>/dev/null
grep '^region' "$OUT/pcs.txt" | awk '{printf "CTL_PROBE region %3d: %8.1f cycles per benchmark step\n", $2, $3 / 64}'
[ $# -gt 0 ] || set -- ControllerQ:: OdometryQ:: __mul __div __udiv
python3 "$ROOT/bench/control_avr/profile.py" "$OUT/bench_g.elf" "$OUT/pcs.txt" 64 "$@"
