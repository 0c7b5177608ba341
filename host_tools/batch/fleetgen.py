"""``python -m host_tools.batch.fleetgen OUT [--robots 5] [--days 10] [--duration 2]``: a
generated fleet for the batch benchmark and tests, recorded with the truth simulator
(``host_tools.truth.simulate_run``) as the tree ``OUT/<robot>/<date>/run-<k>/``.

Every robot drives the same experiments each day (other seeds, so other noise).  The robots
(cycled when there are more than five):

* ``wear``: its wheels wear, the effective radius shrinks linearly day by day;
* ``sag``: its battery sags, the driver's voltage drop grows linearly day by day;
* ``bigwheel``: wheels larger than nominal, but constant (an effect that does not drift);
* ``nominal``: nothing left out of the model.

The truth (which robot drifts in what) is written to ``OUT.labels.json`` beside the tree,
never inside it.
"""
from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import sys

from host_tools.params import ROBOT
from host_tools.suite.cases import STD

R = ROBOT["r"]
#: (kind, effects as a function of the day index) of the robots, in order
KINDS = {
    "wear": lambda d: {"wheel_radius": {"r_eff": R * (0.984 - 0.003 * d)}},
    "sag": lambda d: {"driver_voltage_drop": {"volts": 0.6 + 0.1 * d}},
    "bigwheel": lambda d: {"wheel_radius": {"r_eff": R * 1.025}},
    "nominal": lambda d: {},
}
ORDER = ("wear", "sag", "bigwheel", "nominal", "nominal")
#: the drifting parameter of each drifting kind
DRIFTS = {"wear": "wheel_radius.r_eff", "sag": "driver_voltage_drop.volts"}
#: references of each day's runs: the suite's standard experiments (line, two arcs)
EXPERIMENTS = [ref for ref, _clamp, _dur in STD]


def robot_kinds(n: int) -> list[tuple[str, str]]:
    """(robot name, kind) of ``n`` robots."""
    return [(f"robot{i + 1:02d}", ORDER[i % len(ORDER)]) for i in range(n)]


def generate(out: str, robots: int = 5, days: int = 10, duration_s: float = 2.0,
             runs: int = 2, start: str = "2026-11-01", seed: int = 0) -> dict:
    """Write the fleet; returns the labels (also written to ``<out>.labels.json``)."""
    from host_tools import truth
    d0 = dt.date.fromisoformat(start)
    labels = {"format": "ddfleet-labels/1", "robots": {}}
    for i, (name, kind) in enumerate(robot_kinds(robots)):
        labels["robots"][name] = {"kind": kind, "drift": DRIFTS.get(kind), "days": {}}
        for d in range(days):
            date = (d0 + dt.timedelta(days=d)).isoformat()
            eff = KINDS[kind](d)
            labels["robots"][name]["days"][date] = eff
            for k, ref in enumerate(EXPERIMENTS[:runs]):
                truth.simulate_run(os.path.join(out, name, date, f"run-{k}"), ref, eff,
                                   duration_s=duration_s,
                                   seed=seed + 100000 * i + 100 * d + k, overwrite=True)
    with open(os.path.abspath(out).rstrip(os.sep) + ".labels.json", "w") as fh:
        json.dump(labels, fh, indent=1)
    return labels


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m host_tools.batch.fleetgen",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("out")
    ap.add_argument("--robots", type=int, default=5)
    ap.add_argument("--days", type=int, default=10)
    ap.add_argument("--runs", type=int, default=2, help="runs per day, 1..%d" % len(EXPERIMENTS))
    ap.add_argument("--duration", type=float, default=2.0, help="run length, s")
    ap.add_argument("--start", default="2026-11-01", help="first day, YYYY-MM-DD")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    if not (1 <= a.robots <= 1000 and 1 <= a.days <= 3660 and 1 <= a.runs <= len(EXPERIMENTS)
            and 0.5 <= a.duration <= 600):
        print("error: --robots 1..1000, --days 1..3660, --runs 1..3, --duration 0.5..600 s",
              file=sys.stderr)
        return 2
    generate(a.out, a.robots, a.days, a.duration, a.runs, a.start, a.seed)
    print(f"{a.robots} robots x {a.days} days under {a.out}; truth in "
          f"{os.path.abspath(a.out).rstrip(os.sep)}.labels.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
