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
#   7. static checks: ruff (lint), mypy (types), pio check (cppcheck on src/ and lib/);
#      configured in pyproject.toml and platformio.ini, see docs/ARCHITECTURE.md "Code rules"
set -uo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
T_START=$SECONDS
bash scripts/setup.sh || { echo "test: setup failed" >&2; exit 1; }
source scripts/env.sh

failed=()
times=("setup $((SECONDS - T_START)) s")
LOGS="$(mktemp -d)"
trap 'rm -rf "$LOGS"' EXIT
step() {
    local name="$1"; shift
    local t0=$SECONDS
    echo
    echo "=== test: $name: $*"
    "$@" 2>&1 | tee "$LOGS/$name.log"
    local rc=${PIPESTATUS[0]} took=$((SECONDS - t0))
    times+=("$name $took s")
    if [[ $rc == 0 ]]; then
        echo "=== test: $name: ok ($took s)"
    else
        echo "=== test: $name: FAILED (exit $rc, $took s)"
        failed+=("$name")
    fi
}
# One line with each step's wall time (set-up included) and the total, for the CI log.
step_times() {
    local out="" t
    for t in "${times[@]}"; do out+="${out:+, }$t"; done
    echo "=== test: times: $out; total $((SECONDS - T_START)) s"
}

# Test cases counted from the runners' own summary lines (PlatformIO: "N test cases: ...",
# pytest: "N passed, M failed"), for one closing line over all steps.
count_cases() {
    local passed=0 failed_n=0 line n
    while IFS= read -r line; do
        if [[ $line =~ ([0-9]+)\ test\ cases:\ (([0-9]+)\ failed,\ )?([0-9]+)\ succeeded ]]; then
            failed_n=$((failed_n + ${BASH_REMATCH[3]:-0}))
            passed=$((passed + ${BASH_REMATCH[4]}))
        elif [[ $line =~ ^=*\ ?(([0-9]+)\ failed,\ )?([0-9]+)\ passed ]]; then
            failed_n=$((failed_n + ${BASH_REMATCH[2]:-0}))
            passed=$((passed + ${BASH_REMATCH[3]}))
        elif [[ $line =~ ^=*\ ?([0-9]+)\ failed ]]; then
            failed_n=$((failed_n + ${BASH_REMATCH[1]}))
        fi
    done < <(cat "$LOGS"/*.log 2>/dev/null | sed -e 's/\x1b\[[0-9;]*m//g')
    echo "tests: $passed passed, $failed_n failed"
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
step python    .venv/bin/python -m pytest -q --durations=15 host_tools/tests
step ruff      .venv/bin/ruff check host_tools bench sim scripts protocol params
step mypy      .venv/bin/mypy
step cppcheck  pio check -e megaatmega2560 -e native --fail-on-defect low

echo
if ((${#failed[@]})); then
    echo "=== test: FAILED steps: ${failed[*]}"
    count_cases
    step_times
    exit 1
fi
echo "=== test: all steps passed"
count_cases
step_times
