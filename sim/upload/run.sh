#!/bin/sh
# A simulated Arduino Mega 2560 to upload to: builds sim/upload/upload_sim.c with the one host
# build recipe (host_tools/_build.py, target upload_sim) and runs it with the board's stk500v2
# bootloader and fuses (Debian arduino-core-avr, unpacked by scripts/setup.sh). Prints the USB
# serial pty (upload there: pio run -e megaatmega2560 -t upload --upload-port PTY) and the XBee pty.
# Usage: sim/upload/run.sh [--uart0-link PATH] [--uart2-link PATH]
set -e
root="$(cd "$(dirname "$0")/../.." && pwd)"
export PYTHONPATH="$root${PYTHONPATH:+:$PYTHONPATH}"
"$root/.venv/bin/python" -m host_tools._build upload_sim >/dev/null
exec "$root/.venv/bin/python" -m host_tools.upload_sim "$@"
