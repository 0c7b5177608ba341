#!/usr/bin/env python3
"""Benchmark: how fast the host decodes telemetry frames (goal >= 10 MB/s; the radio link
carries ~4.5 kB/s).  Prints figures; asserts nothing.

    python3 bench/logger/bench_decode.py [--mb 20] [--chunk 4096]

Stages measured on the same byte stream of realistic telemetry frames (changing values, so
COBS has to handle zero bytes inside the bodies):
  1. StreamDecoder.feed          delimit + COBS + CRC + version -> verified frames
  2. + struct unpack             raw field tuples
  3. + logger rows               scaled physical values, as written to telemetry.csv (no disk)
"""
from __future__ import annotations

import argparse
import os
import random
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

from host_tools import protocol as P  # noqa: E402
from host_tools.logger import TelemetryColumns  # noqa: E402


def make_stream(target_bytes: int) -> tuple[bytes, int]:
    d = P.definition()
    msg = d.by_name["Telemetry"]
    names = msg.field_names()
    rnd = random.Random(0)
    frames = []
    t_us = 0
    for i in range(2000):  # 2000 distinct frames, repeated with new seq numbers below
        v = dict.fromkeys(names, 0)
        w = 2000 + rnd.randint(-300, 300)
        v.update(t_us=t_us, enc_r=i * 12, enc_l=i * 11, omega_r=w, omega_l=w - 50, omega_ref_r=2000,
                 omega_ref_l=2000, tau_cmd_r=rnd.randint(-900, 900), tau_cmd_l=rnd.randint(-900, 900),
                 tau_max=950, pwm_r=rnd.randint(-10000, 10000), pwm_l=rnd.randint(-10000, 10000),
                 x_odo=i * 1460, y_odo=rnd.randint(-500, 500), phi_odo=rnd.randint(-3000, 3000),
                 inner_last=rnd.randint(100, 900), inner_max=900, outer_last=rnd.randint(200, 2000),
                 outer_max=2000, telemetry_last=300, telemetry_max=350, status=1 | 2, current_r=200,
                 current_l=190, stack_hwm=812)
        frames.append([v[n] for n in names])
        t_us += 20000
    one = len(d.encode_raw("Telemetry", 0, frames[0]))
    n = target_bytes // one + 1
    out = bytearray()
    for k in range(n):
        out += d.encode_raw("Telemetry", k & 0xFFFF, frames[k % len(frames)])
    return bytes(out), n


def bench(stream: bytes, chunk: int, stage: int) -> tuple[float, int]:
    d = P.definition()
    cols = TelemetryColumns(d)
    unpack = d.by_name["Telemetry"].struct.unpack
    dec = P.StreamDecoder(d.version, d.max_payload)
    count = 0
    t0 = time.perf_counter()
    for i in range(0, len(stream), chunk):
        frames = dec.feed(stream[i:i + chunk])
        if stage == 1:
            count += len(frames)
        elif stage == 2:
            for f in frames:
                unpack(f.payload)
            count += len(frames)
        else:
            for f in frames:
                cols.row(unpack(f.payload), f.seq * 0.02, f.seq, 0.0)
            count += len(frames)
    dt = time.perf_counter() - t0
    assert dec.bad_blocks == 0
    return dt, count


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mb", type=float, default=20.0, help="stream size, MB (default 20)")
    ap.add_argument("--chunk", type=int, default=4096, help="bytes per feed() call (default 4096)")
    ap.add_argument("--repeat", type=int, default=3, help="best of N (default 3)")
    a = ap.parse_args()
    stream, n = make_stream(int(a.mb * 1e6))
    d = P.definition()
    link = d.baud / d.bits_per_byte
    la = os.getloadavg()
    print(f"host: {os.cpu_count()} CPUs, load average {la[0]:.1f} (figures drop when the machine is busy)")
    print(f"stream: {len(stream) / 1e6:.1f} MB, {n} telemetry frames of {d.wire_size('Telemetry')} B, "
          f"feed() chunks of {a.chunk} B, best of {a.repeat}")
    labels = {1: "decode (COBS+CRC, verified frames)", 2: "decode + unpack fields",
              3: "decode + unpack + csv row values"}
    for stage in (1, 2, 3):
        best = min(bench(stream, a.chunk, stage)[0] for _ in range(a.repeat))
        mbs = len(stream) / best / 1e6
        print(f"{labels[stage]:38s} {mbs:7.1f} MB/s  {n / best / 1e3:7.1f} kframes/s  "
              f"({mbs * 1e6 / link:,.0f}x the {d.baud} baud link)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
