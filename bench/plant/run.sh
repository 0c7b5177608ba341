#!/bin/sh
# Build and run the plant benchmark on one core: bench/plant/run.sh
set -e
cd "$(dirname "$0")/../.."
mkdir -p .build/bench
g++ -std=c++14 -O2 -Wall -Wextra -Ilib/slipmodel/src bench/plant/bench_plant.cpp \
    host_tools/native/slipmodel_capi.cpp lib/slipmodel/src/slipmodel/*.cpp -o .build/bench/bench_plant
if command -v taskset >/dev/null 2>&1; then exec taskset -c 0 .build/bench/bench_plant; fi
exec .build/bench/bench_plant
