#!/usr/bin/env python3
"""Benchmark: the run reader's peak memory per byte of telemetry.csv and how soon it refuses
a bad header.  Prints figures; asserts nothing (the goal, issue 24: peak <= 3x the file size;
a bad header refused in about the time it takes to read the header).

    python3 bench/runfmt/bench_reader.py [--sizes-mb 10 50 100] [--header-mb 500] [--dir DIR]

Telemetry is written like the logger's (the spec columns, seq, host_t_s and every other
Telemetry field of protocol.json, values of realistic widths).  Each load runs in a fresh
child process; its peak resident memory (ru_maxrss) less that of a child that only imports
the reader is the reader's peak.  The header figure: a file of --header-mb whose header
lacks a required column, time to the refusal, next to the time to read its header line.
"""
from __future__ import annotations

import argparse
import os
import random
import shutil
import subprocess
import sys
import tempfile
import time

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..")
sys.path.insert(0, ROOT)

from host_tools import protocol as P  # noqa: E402
from host_tools.logger import TelemetryColumns  # noqa: E402

CHILD = r"""
import resource, sys, time
sys.path.insert(0, sys.argv[1])
from host_tools import runfmt
if sys.argv[2] != "-":
    t0 = time.perf_counter()
    try:
        run = runfmt.load_run(sys.argv[2], check_units=False)
        rows = run.telemetry["t_s"].size
    except runfmt.RunFormatError as exc:
        rows = "refused: " + str(exc)[:80]
    dt = time.perf_counter() - t0
else:
    rows, dt = 0, 0.0
print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024, dt, rows, sep="\t")
"""


def _child(path: str) -> tuple[int, float, str]:
    out = subprocess.run([sys.executable, "-c", CHILD, ROOT, path], capture_output=True, text=True,
                         check=True).stdout.strip().split("\t")
    return int(out[0]), float(out[1]), out[2]


def make_run(folder: str, target_bytes: int, drop: str | None = None) -> int:
    """A run folder whose telemetry.csv holds about ``target_bytes``; returns its size."""
    d = P.definition()
    cols = TelemetryColumns(d).columns
    if drop:
        cols = [c for c in cols if c != drop]
    os.makedirs(folder)
    with open(os.path.join(folder, "meta.json"), "w") as fh:
        fh.write('{"format": "ddrun/1", "experiment": "bench"}\n')
    rng = random.Random(1)
    block = []
    for i in range(2000):  # a block of realistic rows, repeated with increasing time
        row = []
        for c in cols:
            if c in ("t_s", "seq", "host_t_s"):
                row.append(None)
            elif c.startswith(("enc_", "status", "failsafe", "boot")) or c.endswith(("_cyc", "overruns")):
                row.append(str(rng.randint(0, 40000)))
            else:
                row.append(f"{rng.uniform(-30, 30):.4f}")
        block.append(row)
    it = cols.index("t_s")
    isq = cols.index("seq") if "seq" in cols else None
    ih = cols.index("host_t_s") if "host_t_s" in cols else None
    path = os.path.join(folder, "telemetry.csv")
    n = 0
    with open(path, "w", buffering=1 << 20) as fh:
        fh.write(",".join(cols) + "\n")
        while fh.tell() < target_bytes:
            lines = []
            for row in block:
                row[it] = f"{0.02 * (n + 1):.6f}"
                if isq is not None:
                    row[isq] = str(n & 0xFFFF)
                if ih is not None:
                    row[ih] = f"{0.02 * n + 0.003:.4f}"
                lines.append(",".join(row))
                n += 1
            fh.write("\n".join(lines) + "\n")
    return os.path.getsize(path)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes-mb", type=float, nargs="+", default=[10, 50, 100])
    ap.add_argument("--header-mb", type=float, default=500)
    ap.add_argument("--dir", default=None, help="scratch folder (default: a temporary one)")
    a = ap.parse_args()
    scratch = tempfile.mkdtemp(prefix="bench-runfmt-", dir=a.dir)
    try:
        base, _, _ = _child("-")
        print(f"baseline child (imports only): {base / 2**20:.0f} MB")
        print(f"{'telemetry.csv':>14s} {'rows':>9s} {'peak - base':>12s} {'ratio':>6s} {'load s':>7s}")
        for mb in a.sizes_mb:
            folder = os.path.join(scratch, f"run{mb:g}")
            size = make_run(folder, int(mb * 2**20))
            peak, dt, rows = _child(folder)
            print(f"{size / 2**20:11.1f} MB {rows:>9s} {(peak - base) / 2**20:9.0f} MB "
                  f"{(peak - base) / size:6.2f} {dt:7.1f}")
            shutil.rmtree(folder)
        if a.header_mb > 0:
            folder = os.path.join(scratch, "badheader")
            size = make_run(folder, int(a.header_mb * 2**20), drop="omega_l")
            t0 = time.perf_counter()
            with open(os.path.join(folder, "telemetry.csv"), "rb") as fh:
                fh.readline()
            t_header = time.perf_counter() - t0
            peak, dt, rows = _child(folder)
            print(f"bad header in {size / 2**20:.0f} MB: {rows}")
            print(f"  refused after {dt * 1e3:.2f} ms (reading the header line alone: "
                  f"{t_header * 1e3:.2f} ms), peak - base {(peak - base) / 2**20:.1f} MB")
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


if __name__ == "__main__":
    main()
