#!/bin/sh
# Builds the firmware-in-the-loop simulator into .build/fil/fil (libsimavr from the
# provisioned PlatformIO package tool-simavr, lib/slipmodel and lib/protocol from the tree).
# Usage: sim/fil/build.sh        (prints the path of the binary)
set -e
root="$(cd "$(dirname "$0")/../.." && pwd)"
core="${PLATFORMIO_CORE_DIR:-$root/.platformio}"
simavr="$core/packages/tool-simavr"
if [ ! -f "$simavr/include/simavr/sim_avr.h" ]; then
    echo "sim/fil/build.sh: libsimavr headers not found in $simavr/include (run scripts/setup.sh)" >&2
    exit 2
fi
libdir="$simavr/lib/x86_64-linux-gnu"
[ -d "$libdir" ] || libdir="$simavr/lib"
out="$root/.build/fil"
mkdir -p "$out"
srcs="$root/sim/fil/fil.cpp $root/lib/slipmodel/src/slipmodel/*.cpp $root/lib/protocol/src/protocol/*.cpp"
# rebuild only when a source or header (or this script) is newer than the binary
deps="$root/sim/fil $root/lib/slipmodel/src $root/lib/protocol/src $root/include/board.h"
if [ -x "$out/fil" ] && [ -z "$(find $deps -newer "$out/fil" 2>/dev/null)" ]; then
    echo "$out/fil"
    exit 0
fi
g++ -std=c++14 -O2 -Wall -Wextra \
    -I"$simavr/include" -I"$simavr/include/simavr" \
    -I"$root/lib/slipmodel/src" -I"$root/lib/protocol/src" -I"$root/include" \
    -o "$out/fil.tmp" $srcs \
    -L"$libdir" -Wl,-rpath,"$libdir" -lsimavr  # (libsimavr brings its own libelf dependency; fil.cpp reads ELF symbols itself)
mv "$out/fil.tmp" "$out/fil"
echo "$out/fil"
