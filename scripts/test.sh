#!/usr/bin/env bash
# The project's test command (README, second command; CI runs exactly this).
# Provisions what is missing, then runs every test suite and exits non-zero if any fails:
#   1. native Unity tests (pio test -e native)
#   2. embedded Unity tests on the simulated ATmega2560 (pio test -e simavr)
#   3. the firmware build with its size check (pio run -e megaatmega2560)
#   4. the firmware on simavr: encoder ISR cycles and edge-rate sweep, system checks over the
#      XBee link (sim/isr_bench/run.sh)
#   5. the timing budgets on a firmware-in-the-loop recording (48 rad/s^2 straight line)
#   6. the Python tests of host_tools (pytest), firmware in the loop included
set -uo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
bash scripts/setup.sh || { echo "test: setup failed" >&2; exit 1; }
source scripts/env.sh

failed=()
step() {
    local name="$1"; shift
    echo
    echo "=== test: $name: $*"
    if "$@"; then
        echo "=== test: $name: ok"
    else
        echo "=== test: $name: FAILED (exit $?)"
        failed+=("$name")
    fi
}

step native    pio test -e native
step simavr    pio test -e simavr --without-uploading
step firmware  pio run -e megaatmega2560
step fw-sim    bash sim/isr_bench/run.sh .pio/build/megaatmega2560/firmware.elf
fil_timing() {
    rm -rf .build/ci/fil-48
    .venv/bin/python -m host_tools fil record --out .build/ci/fil-48 --accel 48 --clamp off \
        && .venv/bin/python -m host_tools timing --run .build/ci/fil-48
}
step timing    fil_timing
step python    .venv/bin/python -m pytest -q host_tools/tests

echo
if ((${#failed[@]})); then
    echo "=== test: FAILED steps: ${failed[*]}"
    exit 1
fi
echo "=== test: all steps passed"
