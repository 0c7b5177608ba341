#!/bin/sh
# Builds the harness and runs it on a firmware ELF (default: the direct avr-g++ build).
# Usage: sim/isr_bench/run.sh [firmware.elf]
set -e
cd "$(dirname "$0")/../.."
mkdir -p .build
gcc -O2 -Wall -Wextra -o .build/isr_bench sim/isr_bench/isr_bench.c -lsimavr -lelf
exec .build/isr_bench "${1:-.build/firmware/firmware.elf}"
