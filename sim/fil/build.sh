#!/bin/sh
# Builds the firmware-in-the-loop simulator into .build/fil/fil (sim/common's libsimavr harness
# recipe; lib/slipmodel and lib/protocol from the tree).
# Usage: sim/fil/build.sh        (prints the path of the binary)
[ -n "$BASH_VERSION" ] || exec bash "$0" "$@"  # host_tools/fil.py runs it with sh
set -e
root="$(cd "$(dirname "$0")/../.." && pwd)"
. "$root/sim/common/harness.sh"
out="$root/.build/fil"
mkdir -p "$out"
# rebuild only when a source or header (or this script) is newer than the binary
deps="$root/sim/fil $root/lib/slipmodel/src $root/lib/protocol/src $HARNESS_DEPS"
if [ -x "$out/fil" ] && [ -z "$(find $deps -newer "$out/fil" 2>/dev/null)" ]; then
    echo "$out/fil"
    exit 0
fi
harness_build "$out/fil.tmp" "$root"/sim/fil/*.cpp "$root"/lib/slipmodel/src/slipmodel/*.cpp \
    "$root"/lib/protocol/src/protocol/*.cpp -I"$root/lib/slipmodel/src" -I"$root/lib/protocol/src" >&2
mv "$out/fil.tmp" "$out/fil"
echo "$out/fil"
