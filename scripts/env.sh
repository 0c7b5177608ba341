# Environment of the project's tools. Source it to use `pio`, avr-gcc and simavr from a shell:
#   source scripts/env.sh
# It only sets variables; scripts/setup.sh installs what they point at.
_dd_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
export PLATFORMIO_CORE_DIR="$_dd_root/.platformio"   # never the user's ~/.platformio
export PLATFORMIO_DISABLE_UPGRADE_CHECK=true
export PLATFORMIO_SETTING_ENABLE_TELEMETRY=no
export PLATFORMIO_DISABLE_PROGRESSBAR=true
# The provisioned simavr (bin/simavr, include/simavr, lib/x86_64-linux-gnu/libsimavr.so) for
# host programs that link libsimavr: -I$DD_SIMAVR/include/simavr -L$DD_SIMAVR/lib/x86_64-linux-gnu
export DD_SIMAVR="$PLATFORMIO_CORE_DIR/packages/tool-simavr"
export DD_SIMAVR_LIBDIR="$DD_SIMAVR/lib/x86_64-linux-gnu"
# Compile and link flags of a host program that uses libsimavr (#include <simavr/sim_avr.h>).
export DD_SIMAVR_CFLAGS="-I$DD_SIMAVR/include"
export DD_SIMAVR_LIBS="-L$DD_SIMAVR_LIBDIR -Wl,-rpath,$DD_SIMAVR_LIBDIR -lsimavr"
# Python environment first, then the provisioned avr-gcc 5.4 and simavr 1.6.
export PATH="$_dd_root/.venv/bin:$PLATFORMIO_CORE_DIR/packages/toolchain-atmelavr/bin:$DD_SIMAVR/bin:$PATH"
unset _dd_root
