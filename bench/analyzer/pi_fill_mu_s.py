"""Measurement: what sets a fitted mu_s under a fast ``pi`` loop with lost frames (heldback32's
``hb32_tr_friction_coefficient``: true mu_s 0.181 / mu_k 0.179, recorder
``pi_loop4p4_ticks_drop38``, fitted mu_s 0.2598 with a profile set of 0.2595-0.2685).

Sub-commands (nice them; one process each; seconds each):

  thin TICK_RUNS PATTERN_RUNS OUT [--period S]
      the runs of TICK_RUNS (recorded with a frame at every inner tick, ``tel_s`` = ``inner_s``,
      no loss: ``stribeck_recorder.py generate ... --recorder tel_s=0.0044,tel_drop=0``) with
      their telemetry thinned to the frames of PATTERN_RUNS (the case's own recording: the tick
      nearest each of its frames, so its 20 ms grid and its lost frames) or, with
      ``--period``, to one frame every S seconds on the same grid without loss; meta.json's
      telemetry period set to match.  The physics (every tick's command, count and pose) is
      the tick recording's: only what the recorder reports differs.

  profile RUNS MU_K [--grid MU_S,...]
      the analyzer's fit cost (``Problem.residual``, its sum of squares) per run over mu_s at
      fixed MU_K, and the profile set's threshold at the grid's best point (3.84 and 2.71 times
      ``solver.residual_variance`` with two fitted coordinates).

  step RUNS MU_K MU_S_A MU_S_B RUN_INDEX
      where the cost changes between two mu_s on one run: per fit channel its sum of
      squares (deflated residual in floors) at each, and the four samples that change most.

Example:

  B=bench/analyzer/pi_fill_mu_s.py; S=bench/analyzer/stribeck_recorder.py; D=/tmp/fc
  C=hb32_tr_friction_coefficient
  nice .venv/bin/python $S generate heldback32 $C $D/tick --recorder tel_s=0.0044,tel_drop=0
  nice .venv/bin/python $B thin $D/tick/runs/$C /work/wt/score-data/heldback32/runs/$C $D/thin_drop
  nice .venv/bin/python $B thin $D/tick/runs/$C /work/wt/score-data/heldback32/runs/$C $D/thin_20 --period 0.02
  for v in tick/runs/$C thin_drop thin_20; do nice .venv/bin/python $B profile $D/$v 0.1852; done
"""
from __future__ import annotations

import argparse
import csv
import json
import shutil
from pathlib import Path

import numpy as np

GRID = (0.179, 0.182, 0.185, 0.19, 0.2, 0.21, 0.22, 0.23, 0.24, 0.25, 0.255, 0.258, 0.26, 0.265,
        0.27, 0.28)


def _runs(d: Path) -> list[str]:
    return sorted(str(p) for p in d.iterdir() if p.name.startswith("run-"))


def thin(a: argparse.Namespace) -> None:
    src, pat, out = Path(a.tick_runs), Path(a.pattern_runs), Path(a.out)
    for rd in _runs(src):
        name = Path(rd).name
        dst = out / name
        shutil.rmtree(dst, ignore_errors=True)
        shutil.copytree(rd, dst)
        with open(Path(rd) / "telemetry.csv") as fh:
            rows = list(csv.reader(fh))
        head, body = rows[0], rows[1:]
        t = np.array([float(r[0]) for r in body])
        if a.period:
            with open(pat / name / "telemetry.csv") as fh:
                t0 = float(list(csv.reader(fh))[1][0])
            want = np.arange(t0, t[-1] + 1e-9, a.period)
        else:
            with open(pat / name / "telemetry.csv") as fh:
                want = np.array([float(r[0]) for r in list(csv.reader(fh))[1:]])
        idx = sorted({int(np.argmin(np.abs(t - w))) for w in want})
        with open(dst / "telemetry.csv", "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(head)
            w.writerows(body[i] for i in idx)
        meta = json.loads((dst / "meta.json").read_text())
        meta["periods_s"]["telemetry"] = a.period or 0.02
        (dst / "meta.json").write_text(json.dumps(meta, indent=2))
        print(f"{name}: {len(body)} -> {len(idx)} frames, largest gap "
              f"{np.max(np.diff(t[idx])) * 1e3:.0f} ms, first frames {np.round(t[idx][:4], 3)}")


def profile(a: argparse.Namespace) -> None:
    from host_tools.analyzer.fit.solver import effective_n, residual_variance
    from host_tools.analyzer.pipeline import front
    runs = _runs(Path(a.runs))
    pr = front(runs).det.problem
    grid = [float(g) for g in a.grid.split(",")] if a.grid else list(GRID)
    fx = "friction_coefficient"
    base = [float(np.sum(pr.residual({}, [j]) ** 2)) for j in range(len(runs))]
    print(f"{a.runs}\n  nominal cost per run " + " ".join(f"{b:8.1f}" for b in base))
    best = (np.inf, grid[0])
    for s in grid:
        per = [float(np.sum(pr.residual({fx: {"mu_s": s, "mu_k": a.mu_k}}, [j]) ** 2))
               for j in range(len(runs))]
        best = min(best, (sum(per), s))
        print(f"  mu_s {s:.3f} total {sum(per):9.1f}  per run " + " ".join(f"{p:8.1f}" for p in per))
    r = pr.residual({fx: {"mu_s": best[1], "mu_k": a.mu_k}}, list(range(len(runs))))
    sc = residual_variance(r, 2)
    print(f"  best mu_s {best[1]:.3f}: n {r.size}, n_eff {effective_n(r):.0f}, scale {sc:.3f}; "
          f"profile threshold 3.84 x scale = {3.84 * sc:.2f} (one-sided 2.71 x = {2.71 * sc:.2f})")


def step(a: argparse.Namespace) -> None:
    from host_tools.analyzer.pipeline import front
    runs = _runs(Path(a.runs))
    f = front(runs)
    pr = f.det.problem
    fl = pr.floors
    fx = "friction_coefficient"
    j = a.run_index
    ca = pr.sim_channels({fx: {"mu_s": a.mu_s_a, "mu_k": a.mu_k}}, [j], True, fit_only=True)[0]
    cb = pr.sim_channels({fx: {"mu_s": a.mu_s_b, "mu_k": a.mu_k}}, [j], True, fit_only=True)[0]
    tel = f.preps[j].run.telemetry["t_s"]
    print(f"{Path(runs[j]).name}: reported frames before 0.3 s: {np.round(tel[tel < 0.3], 3)}")
    for c in ca:
        ra = ca[c].deflated(fl[c]) / fl[c]
        rb = cb[c].deflated(fl[c]) / fl[c]
        k = np.argsort(-np.abs(rb ** 2 - ra ** 2))[:4]
        print(f"  {c:12} cost {np.sum(ra ** 2):7.2f} -> {np.sum(rb ** 2):7.2f}; most at t "
              + ", ".join(f"{ca[c].t[i]:.3f} ({ra[i]:+.2f} -> {rb[i]:+.2f})" for i in k))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    t = sub.add_parser("thin")
    t.add_argument("tick_runs")
    t.add_argument("pattern_runs")
    t.add_argument("out")
    t.add_argument("--period", type=float, default=0.0)
    q = sub.add_parser("profile")
    q.add_argument("runs")
    q.add_argument("mu_k", type=float)
    q.add_argument("--grid", default="")
    s = sub.add_parser("step")
    s.add_argument("runs")
    s.add_argument("mu_k", type=float)
    s.add_argument("mu_s_a", type=float)
    s.add_argument("mu_s_b", type=float)
    s.add_argument("run_index", type=int)
    a = p.parse_args()
    {"thin": thin, "profile": profile, "step": step}[a.cmd](a)


if __name__ == "__main__":
    main()
