#!/usr/bin/env python3
"""Per-source-line cycle profile of functions of the control benchmark.

Usage: profile.py bench_g.elf pcs.txt calls FUNCTION_SUBSTRING...
pcs.txt comes from profile.c ("pc cycles"). For every address inside the named functions the
cycles are attributed to the outermost inlined frame that lies in a lib/control .cpp file (the
line of the step function that caused them), divided by `calls` (cycles per call)."""
import re
import subprocess
import sys
from collections import defaultdict


def main():
    elf, pcs_file, calls = sys.argv[1], sys.argv[2], int(sys.argv[3])
    wanted = sys.argv[4:]
    syms = []
    for line in subprocess.run(["avr-nm", "-S", "-C", elf], capture_output=True, text=True).stdout.splitlines():
        m = re.match(r"([0-9a-f]+) ([0-9a-f]+) [tTwW] (.*)", line)
        if m and any(w in m.group(3) for w in wanted):
            syms.append((int(m.group(1), 16), int(m.group(2), 16), m.group(3)))
    cyc = {}
    for line in open(pcs_file):
        m = re.fullmatch(r"([0-9a-f]+) ([0-9]+)", line.strip())
        if m:  # other lines are the benchmark's own UART output
            cyc[int(m.group(1), 16)] = int(m.group(2))
    for start, size, name in sorted(set(syms)):
        pcs = sorted(a for a in cyc if start <= a < start + size)
        if not pcs:
            continue
        out = subprocess.run(["avr-addr2line", "-a", "-i", "-e", elf] + [hex(a) for a in pcs],
                             capture_output=True, text=True).stdout.splitlines()
        frames = defaultdict(list)
        cur = None
        for l in out:
            if l.startswith("0x"):
                cur = int(l, 16)
            else:
                frames[cur].append(l.split(" (")[0].split("/")[-1])
        per_line = defaultdict(int)
        for a in pcs:
            fr = [f for f in frames[a] if re.search(r"(cascade_q|odometry|reference|cascade)\.cpp", f)]
            key = fr[-1] if fr else (frames[a][-1] if frames[a] else "?")
            per_line[key] += cyc[a]
        total = sum(cyc[a] for a in pcs)
        print(f"== {name}: {total / calls:.0f} cycles per call (own code, callees excluded)")
        for k in sorted(per_line, key=lambda k: (k.split(":")[0], int(k.split(":")[1]) if k.split(":")[-1].isdigit() else 0)):
            print(f"  {k:34s} {per_line[k] / calls:8.1f}")


if __name__ == "__main__":
    main()
