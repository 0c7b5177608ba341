#!/usr/bin/env bash
# Build and run the plant benchmark on one core: bench/plant/run.sh
set -e
cd "$(dirname "$0")/../.."
. scripts/env.sh  # the project's Python (host_tools._build: the one host build recipe)
exe=$(python -m host_tools._build bench_plant)
if command -v taskset >/dev/null 2>&1; then exec taskset -c 0 "$exe"; fi
exec "$exe"
