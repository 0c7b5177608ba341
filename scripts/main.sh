#!/usr/bin/env bash
# The project's main job (README, first command), on built-in data:
#   1. provisions what is missing (scripts/setup.sh);
#   2. builds the ATmega2560 firmware and prints its flash and RAM use;
#   3. runs the host demo: the thesis reproduction and the mismatch analyzer, results in out/.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
bash scripts/setup.sh
source scripts/env.sh
echo "=== main: firmware (pio run -e megaatmega2560)"
pio run -e megaatmega2560
echo "=== main: host demo (python -m host_tools demo --out out)"
.venv/bin/python -m host_tools demo --out out
