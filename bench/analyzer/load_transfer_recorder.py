"""Measurement: how many noise floors a load transfer makes on a case's slip runs under the
case's own recorder, with the recorder's knobs changed one at a time, at other centre-of-mass
heights and without the effect (the same seeds: the same references, noise draws and plant).

Each variant ``NAME:OPTIONS`` (OPTIONS: comma-separated recorder ``KEY=VALUE`` as
``suite bench --recorder``, and ``h=`` in m for the load transfer's height, ``h=0`` for none)
generates the case (``--set``, ``--case``) into ``OUT/NAME`` (``--reuse``: kept if there), runs
the analyzer on it and prints: the verdict and selected effects with their parameters; the
nominal model's normalized RMS over the fit channels (noise = 1, as the report's
"Disagreement in noise floors"); the report's largest window (``localization``, noise
floors); and the largest single samples of the fit channels in noise floors widened by the
replay's uncertainty (the residual over ``series/<run>.csv``'s ``band`` / 3, as every window
test sees it), with their run, channel and time, and how many fit-channel samples there are.

Usage (one process; a MuJoCo slip case ~1-2 min per variant on the shared machine):

  PYTHONPATH=. .venv/bin/python bench/analyzer/load_transfer_recorder.py \\
      --set heldback30 --case hb30_mj_load_transfer --out /tmp/lt \\
      --variant own: --variant drop0:tel_drop=0 --variant tel20:tel_s=0.02 \\
      --variant full:tel_s=0.02,tel_drop=0 --variant null:h=0 --variant h90:h=0.09
"""
from __future__ import annotations

import argparse
import csv
import glob
import json
import math
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))

from host_tools.analyzer.replay.channels import FIT_CHANNELS  # noqa: E402
from host_tools.analyzer.report.series import BAND_K  # noqa: E402
from host_tools.suite import cases as C  # noqa: E402
from host_tools.suite.bench import bench  # noqa: E402
from host_tools.suite.generate import generate_case  # noqa: E402


def _value(text: str) -> object:
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def samples(report_dir: str) -> list[tuple[float, str, str, float]]:
    """Every fit-channel sample of the nominal duty replay as (|residual| in floors widened by
    the replay's uncertainty, run, channel, t), largest first; the nominal normalized RMS is
    the RMS of these (samples that are no evidence have no band and are left out)."""
    out = []
    for path in sorted(glob.glob(os.path.join(report_dir, "series", "run-*.csv"))):
        run = os.path.basename(path)[:-4]
        with open(path) as fh:
            for row in csv.DictReader(fh):
                if row["replay"] != "duty" or row["channel"] not in FIT_CHANNELS:
                    continue
                band = float(row["band"] or "nan")
                if not math.isfinite(band) or band <= 0:
                    continue
                z = BAND_K * float(row["residual_nominal"]) / band
                out.append((abs(z), run, row["channel"], float(row["t_s"])))
    return sorted(out, reverse=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("--set", required=True)
    ap.add_argument("--case", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--variant", action="append", required=True, metavar="NAME:OPTIONS")
    ap.add_argument("--top", type=int, default=3, help="largest samples printed")
    ap.add_argument("--reuse", action="store_true", help="reuse runs already generated")
    a = ap.parse_args(argv)
    for spec in a.variant:
        name, _, opts = spec.partition(":")
        case = C.get([a.case], which=a.set)[0]
        rec: dict[str, object] = {}
        for kv in filter(None, opts.split(",")):
            k, _, v = kv.partition("=")
            if k != "h":
                rec[k] = _value(v)
            elif float(v) > 0:
                case.effects = {**case.effects, "load_transfer": {"h": float(v)}}
            else:
                case.effects = {e: p for e, p in case.effects.items() if e != "load_transfer"}
                case.expect = "no_mismatch"
        case.recorder = {**case.recorder, **rec}
        out = os.path.join(a.out, name)
        if not (a.reuse and os.path.isdir(os.path.join(out, "runs", case.name))):
            generate_case(case, out, overwrite=True)
        bench(out, [case], jobs=1, regenerate=False, out=lambda s: None)
        rdir = os.path.join(out, "reports", case.name)
        with open(os.path.join(rdir, "report.json")) as fh:
            rep = json.load(fh)
        peak = max((e["peak_noise_floors"] for e in rep.get("localization", [])), default=0.0)
        sel = [(c.get("effect"), c.get("params")) for c in rep.get("selected", [])]
        h = case.effects.get("load_transfer", {}).get("h", 0.0)
        top = samples(rdir)
        print(f"{name}: h {h:.4f}, recorder {case.recorder}: {rep.get('verdict')} {sel}; "
              f"nominal normalized RMS {rep['fit'].get('normalized_rms_before')}; largest "
              f"window {peak:.2f} floors; {len(top)} samples, largest "
              + ", ".join(f"{z:.2f} ({r} {c} {t:.3f} s)" for z, r, c, t in top[:a.top]),
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
