#!/usr/bin/env bash
# Self-test of sim/common's cycle corrections: builds the probe program timing.S with avr-gcc
# and the harness selftest.c, runs it (exit status 1 when a figure differs from the datasheet).
# Usage: bash sim/common/selftest/run.sh
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../../.." && pwd)"
. "$ROOT/scripts/env.sh"
OUT="$ROOT/.build/sim_common"
mkdir -p "$OUT"
avr-gcc -mmcu=atmega2560 -nostartfiles -nostdlib -o "$OUT/timing.elf" "$ROOT/sim/common/selftest/timing.S"
PYTHONPATH="$ROOT${PYTHONPATH:+:$PYTHONPATH}" "$ROOT/.venv/bin/python" -m host_tools._build sim_selftest >/dev/null
"$OUT/selftest" "$OUT/timing.elf"
