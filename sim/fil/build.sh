#!/bin/sh
# Builds the firmware-in-the-loop simulator into .build/fil/fil with the one host build recipe
# (host_tools/_build.py, target fil: sim/fil, lib/slipmodel and lib/protocol from the tree,
# sim/common and the provisioned libsimavr); a no-op when the binary is up to date.
# Usage: sim/fil/build.sh        (prints the path of the binary)
set -e
root="$(cd "$(dirname "$0")/../.." && pwd)"
PYTHONPATH="$root${PYTHONPATH:+:$PYTHONPATH}" exec "$root/.venv/bin/python" -m host_tools._build fil
