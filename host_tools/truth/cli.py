"""``python -m host_tools.truth``: one closed-loop run of the truth simulator from the command
line."""
from __future__ import annotations

import json

from host_tools.control import REF_KINDS as _REF_KINDS
from host_tools.truth.recorder import add_recorder_arguments, recorder_from_args
from host_tools.truth.run import simulate_run


def _parse_effect(text: str) -> tuple[str, dict[str, float]]:
    """``name:param=value,param=value`` -> (name, params)."""
    name, _, rest = text.partition(":")
    params: dict[str, float] = {}
    for item in filter(None, rest.split(",")):
        k, eq, v = item.partition("=")
        if not eq:
            raise ValueError(f"--effect {text!r}: expected name:param=value[,param=value]")
        try:
            params[k.strip()] = float(v)
        except ValueError:
            raise ValueError(f"--effect {text!r}: {v!r} is not a number") from None
    return name.strip(), params


def main(argv=None) -> int:
    """``python -m host_tools.truth RUN_DIR [--ref line|arc|figure_eight|tour|segments]
    [--accel A] [--cruise V] [--radius R] [--segments FILE] [--no-clamp] [--duration T]
    [--seed N] [--effect name:p=v,...]... [--hidden DIR] [recorder variants]``: one closed-loop
    run of the truth simulator written as a run folder (true state to --hidden, never into the
    run). ``--ref tour``: a seeded sequence of speed ramps, stops and turns filling --duration;
    ``--ref segments --segments FILE``: a JSON list of {duration_s, v, omega} (ramps at --accel
    and --alpha)."""
    import argparse
    import sys
    ap = argparse.ArgumentParser(prog="python -m host_tools.truth", description=main.__doc__)
    ap.add_argument("run_dir")
    ap.add_argument("--ref", default="line",
                    choices=list(_REF_KINDS) + ["tour", "reversals", "segments"])
    ap.add_argument("--accel", type=float, default=None,
                    help="m/s^2 (default 1.0; 0.6 for tour and segments, 1.2 for reversals)")
    ap.add_argument("--cruise", type=float, default=0.6, help="m/s")
    ap.add_argument("--radius", type=float, default=0.5, help="m (arc: > 0 turns left)")
    ap.add_argument("--alpha", type=float, default=None,
                    help="rad/s^2 (tour, segments: default 2; reversals: 6)")
    ap.add_argument("--segments", default=None, metavar="FILE",
                    help="JSON list of {duration_s, v, omega} for --ref segments")
    ap.add_argument("--no-clamp", action="store_true", help="tau_max clamp off")
    ap.add_argument("--duration", type=float, default=2.0, help="s")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--effect", action="append", default=[], metavar="NAME:P=V,...")
    ap.add_argument("--hidden", default=None, help="folder for the true state (csv)")
    ap.add_argument("--overwrite", action="store_true")
    ap.add_argument("--engine", choices=("truth", "mujoco"), default="truth",
                    help="the physics the recorder drives: the truth simulator's own or the "
                         "MuJoCo model (host_tools.engines.mujoco_robot; needs the mujoco package)")
    ap.add_argument("--inductance-mh", type=float, default=0.0,
                    help="mujoco engine: the motors' armature inductance, mH")
    add_recorder_arguments(ap)
    a = ap.parse_args(argv)
    try:
        effects = dict(_parse_effect(e) for e in a.effect)
        if a.ref in ("tour", "reversals", "segments"):
            hard = a.ref == "reversals"
            ref = {"kind": a.ref, "accel": (1.2 if hard else 0.6) if a.accel is None else a.accel,
                   "alpha": (6.0 if hard else 2.0) if a.alpha is None else a.alpha}
            if a.ref == "segments":
                if not a.segments:
                    raise ValueError("--ref segments needs --segments FILE")
                with open(a.segments) as fh:
                    ref["segments"] = json.load(fh)
        else:
            ref = {"kind": a.ref, "accel": 1.0 if a.accel is None else a.accel,
                   "cruise": a.cruise, "radius": a.radius}
        path = simulate_run(a.run_dir, ref, effects, clamp=not a.no_clamp,
                            duration_s=a.duration, seed=a.seed, hidden_dir=a.hidden,
                            overwrite=a.overwrite, recorder=recorder_from_args(a),
                            engine=a.engine,
                            engine_options=({"inductance_h": a.inductance_mh / 1e3}
                                            if a.engine == "mujoco" else None))
    except (ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"run written to {path}")
    return 0

