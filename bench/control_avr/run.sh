#!/usr/bin/env bash
# Build the lib/control AVR cycle benchmark the way the firmware is built and run it in simavr.
# Usage (from anywhere): bash bench/control_avr/run.sh      Output: a table of CPU cycles.
set -eu
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
. "$ROOT/scripts/env.sh"  # provisioned avr-gcc, simavr and libsimavr (scripts/setup.sh)
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
  | sed -n '/^BEGIN control_avr/,/^END/p' > "$OUT/table.txt"
grep -v '^avr config' "$OUT/table.txt"
# The same fixed-point sequence on the host: the checksums must agree.
HOST_CHECK=$(cd "$ROOT" && python -m host_tools._build host_check)  # the one host build recipe
# shellcheck disable=SC2046
# Four checksums: the 64-step controller sequence (arc reference), the figure-eight samples,
# a sweep of sin_q15/cos_q15, and arc and eight samples over 8.9 h.
HOST=$("$HOST_CHECK" $(sed -n 's/^avr config//p' "$OUT/table.txt" | tr '\n' ' ') | awk '{print $(NF-3), $(NF-2), $(NF-1), $NF}')
AVR=$(awk '/avr fixed-point checksum/ {print $(NF-3), $(NF-2), $(NF-1), $NF}' "$OUT/table.txt")
if [ -n "$AVR" ] && [ "$HOST" = "$AVR" ]; then echo "AVR and host fixed-point outputs identical (checksums $AVR)";
else echo "MISMATCH: AVR checksum $AVR, host $HOST"; exit 1; fi
grep -q "checks, 0 wrong" "$OUT/table.txt" || { echo "AVR arithmetic self-test FAILED"; exit 1; }
# The fixed-point step functions must not call any soft-float routine (__*sf*).
for fn in _ZN3ctl11ControllerQ10inner_stepEllm _ZN3ctl11ControllerQ10outer_stepERKNS_10RefSampleQE \
          _ZN3ctl14reference_at_qERKNS_14ReferenceSpecQEm _ZN3ctl9OdometryQ6updateEllm \
          _ZN3ctl15kinematic_law_qERKNS_14ControlConfigQERKNS_5PoseQERKNS_10RefSampleQE \
          _ZN4slip11tau_max_q16ERKNS_9TractionQEl _ZN4slip17normal_forces_q16ERKNS_9TractionQEl; do
  if avr-objdump -d "$OUT/bench.elf" | awk "/<$fn>:/,/^\$/" | grep -E 'call.*<__[a-z]*sf[0-9a-z]*>' >/dev/null; then
    echo "FLOAT CALL in fixed-point function $fn"; exit 1
  fi
done
echo "fixed-point step functions call no soft-float routine"
# The goals (lib/control/README.md): every inner step of the firmware's sequence (reset, then
# dt = 25 ms +- jitter) <= 2,000 cycles; the outer step plus the figure-eight reference sample
# <= 10,000 (timed together as the firmware's outer task, and as the sum of the two maxima).
awk '
  /^fixed inner_step firmware/ { inner = $(NF-1) }
  /^fixed outer task, figure eight/ { task = $(NF-1) }
  /^fixed outer task, drive mode/ { drive = $(NF-1) }
  /^fixed outer_step max \+ figure-eight sample max/ { sum = $NF }
  END {
    ok = (inner != "" && task != "" && sum != "" && drive != "" && inner + 0 <= 2000 && task + 0 <= 10000 && sum + 0 <= 10000 && drive + 0 <= 10000)
    printf "goals: inner step (firmware sequence) max %s <= 2000, outer task (eight) max %s, outer + eight maxima %s and outer task (drive) max %s <= 10000: %s\n", inner, task, sum, drive, ok ? "met" : "NOT MET"
    exit ok ? 0 : 1
  }' "$OUT/table.txt"
