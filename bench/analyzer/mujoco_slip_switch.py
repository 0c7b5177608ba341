"""Measurement: how the MuJoCo engine's stick-to-slide switch moves the fitted μs.
``python bench/analyzer/mujoco_slip_switch.py SET CASE OUT [--slip-on 1e-3,5e-3,2e-2]``.

Measurement only (no rule, the engine unchanged).  For each slip speed in ``--slip-on`` the
engine's :data:`host_tools.engines.mujoco_robot.SLIP_ON_M_S` (the contact point's slip speed
above which a wheel's friction switches from μs to μk; the switch back,
:data:`SLIP_OFF_M_S`, at most 0.4 of it) is set in this process, the case is generated with the
firmware's own recorder (``hb33_recorder_misses.py generate SET CASE DIR --default-recorder``:
the case's seeds, references and effect) and analysed (``python -m host_tools analyze``); the
verdict, the selected effects and the friction's μs with its reported set are printed.  A wheel
whose demand passes μs·N creeps at μs below the switch speed before it slides; lib/slipmodel
slides in the step the cone saturates, so the nominal model matches the later slide with a
higher μs (docs/analyzer.md, "heldback34's misses").
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import runpy
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.abspath(os.path.join(HERE, "..", ".."))
sys.path.insert(0, ROOT)


def _generate(set_name: str, case: str, out: str, slip_on: float) -> None:
    from host_tools.engines import mujoco_robot as m
    m.SLIP_ON_M_S = slip_on
    m.SLIP_OFF_M_S = min(m.SLIP_OFF_M_S, 0.4 * slip_on)
    argv = sys.argv
    sys.argv = ["hb33_recorder_misses.py", "generate", set_name, case, out, "--default-recorder"]
    try:
        runpy.run_path(os.path.join(HERE, "hb33_recorder_misses.py"), run_name="__main__")
    except SystemExit as e:
        if e.code not in (0, None):
            raise
    finally:
        sys.argv = argv


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="bench/analyzer/mujoco_slip_switch.py", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("set")
    ap.add_argument("case")
    ap.add_argument("out")
    ap.add_argument("--slip-on", default="1e-3,5e-3,2e-2", help="switch speeds, m/s")
    a = ap.parse_args(argv)
    for v in (float(x) for x in a.slip_on.split(",")):
        d = os.path.join(a.out, f"slip_on_{v:g}")
        pid = os.fork()
        if pid == 0:   # the engine's constant is set in a child, so each speed starts clean
            _generate(a.set, a.case, d, v)
            os._exit(0)
        _, status = os.waitpid(pid, 0)
        if status:
            print(f"slip on {v:g} m/s: generation failed ({status})")
            continue
        runs = sorted(glob.glob(os.path.join(d, "runs", a.case, "run-*")))
        rep = os.path.join(d, "report")
        subprocess.run([sys.executable, "-m", "host_tools", "analyze", *runs, "--out", rep,
                        "--jobs", "1", "--no-plots"], check=True, cwd=ROOT,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        r = json.load(open(os.path.join(rep, "report.json")))
        fr = [s for s in r["selected"] if s["effect"] == "friction_coefficient"]
        mu = ""
        if fr:
            p, iv = fr[0]["params"], fr[0].get("interval", {}).get("mu_s", {})
            mu = (f"mu_s {p['mu_s']:.4f} mu_k {p['mu_k']:.4f}, set {iv.get('kind')} "
                  f"{iv.get('lo')}..{iv.get('hi')}")
        print(f"slip on {v:g} m/s: {r['verdict']} "
              f"{'+'.join(s['effect'] for s in r['selected']) or '-'} {mu}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
