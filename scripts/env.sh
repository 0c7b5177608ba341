# Environment of the project's tools. Source it to use `pio`, avr-gcc and simavr from a shell:
#   source scripts/env.sh
# It only sets variables; scripts/setup.sh installs what they point at.
_dd_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
export PLATFORMIO_CORE_DIR="$_dd_root/.platformio"   # never the user's ~/.platformio
export PLATFORMIO_DISABLE_UPGRADE_CHECK=true
export PLATFORMIO_SETTING_ENABLE_TELEMETRY=no
export PLATFORMIO_DISABLE_PROGRESSBAR=true
# The provisioned simavr (bin/simavr, include/simavr, lib/x86_64-linux-gnu/libsimavr.so). Host
# programs that link libsimavr are built by host_tools/_build.py (python -m host_tools._build).
export DD_SIMAVR="$PLATFORMIO_CORE_DIR/packages/tool-simavr"
# Python environment first, then the provisioned avr-gcc 5.4 and simavr 1.6.
export PATH="$_dd_root/.venv/bin:$PLATFORMIO_CORE_DIR/packages/toolchain-atmelavr/bin:$DD_SIMAVR/bin:$PATH"
unset _dd_root
