# The one build recipe of the host programs that link libsimavr (sourced by bash scripts):
#   . sim/common/harness.sh
#   harness_build OUTPUT SOURCE... [EXTRA_FLAG...]
# compiles SOURCE (C or C++; C++ when any source ends in .cpp) with sim/common/avrsim.c,
# -O2 -Wall -Wextra -Werror, the provisioned libsimavr (scripts/env.sh), the firmware's
# include/ (board.h) and avr-libc's device headers (sim/common/avr_regs.h).
_harness_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
. "$_harness_root/scripts/env.sh"
HARNESS_AVR_INCLUDE="$PLATFORMIO_CORE_DIR/packages/toolchain-atmelavr/lib/avr/include"
HARNESS_FLAGS="-O2 -Wall -Wextra -Werror -I$_harness_root/sim/common -I$_harness_root/include -idirafter $HARNESS_AVR_INCLUDE $DD_SIMAVR_CFLAGS"
# Files a harness binary depends on besides its own sources (for staleness checks).
HARNESS_DEPS="$_harness_root/sim/common $_harness_root/include/board.h $_harness_root/lib/slipmodel/src/slipmodel/params_table.h"

harness_build() {
    _out="$1"
    shift
    if [ ! -f "$DD_SIMAVR/include/simavr/sim_avr.h" ] || [ ! -f "$HARNESS_AVR_INCLUDE/avr/iom2560.h" ]; then
        echo "sim/common/harness.sh: libsimavr or avr-libc headers missing under $PLATFORMIO_CORE_DIR/packages (run scripts/setup.sh)" >&2
        return 2
    fi
    _cxx=""
    for _a in "$@"; do case "$_a" in *.cpp) _cxx=1 ;; esac; done
    mkdir -p "$(dirname "$_out")"
    # shellcheck disable=SC2086
    gcc -std=gnu11 $HARNESS_FLAGS -c "$_harness_root/sim/common/avrsim.c" -o "$_out.avrsim.o" || return 1
    if [ -n "$_cxx" ]; then
        # shellcheck disable=SC2086
        g++ -std=c++14 $HARNESS_FLAGS -o "$_out" "$@" "$_out.avrsim.o" $DD_SIMAVR_LIBS || return 1
    else
        # shellcheck disable=SC2086
        gcc -std=gnu11 $HARNESS_FLAGS -o "$_out" "$@" "$_out.avrsim.o" $DD_SIMAVR_LIBS || return 1
    fi
    rm -f "$_out.avrsim.o"
}
