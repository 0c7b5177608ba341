"""Timing-budget check: ``python -m host_tools timing [--run RUN_DIR]... [--sim SIM.json]...``.

Budgets come from protocol/protocol.json (``timing``: each task's period and cycle budget, the
encoder ISR's cycles per edge, the CPU utilisation limit), the same table the firmware is
generated from.  Measurements come from

(a) a recorded run (telemetry.csv written by ``host_tools log`` or the firmware-in-the-loop
    simulator): per task the columns ``<task>_last_cyc``, ``<task>_max_cyc`` and
    ``<task>_overruns`` (names from the Telemetry message of protocol.json);
(b) simavr measurements in a small JSON file, format ``ddtiming/1``::

        {"format": "ddtiming/1",
         "source": "sim/isr_bench, simavr 1.6, avr-gcc 5.4 -Os",   (free text)
         "f_cpu_hz": 16000000,                                      (optional)
         "isr":   {"encoder": {"cycles_per_event": 58}},            (per edge, corrected: incl.
                                                                     the 5-cycle response + RETI)
         "tasks": {"inner": {"max_cycles": 9000, "samples": 400},   (any subset of the tasks)
                   "outer": {"max_cycles": 21000},
                   "telemetry": {"max_cycles": 6000}},
         "other_isr": [{"name": "uart3_udre", "cycles_per_event": 45, "events_per_s": 4600}]}

A run folder recorded through the firmware-in-the-loop simulator (sim/fil) also holds
``fil.json``; its ``encoder_isr.max_cycles`` (corrected like sim/isr_bench) and per-task
``max_cycles`` are then used as a simavr source automatically (``--no-fil`` to skip).

What is checked (exit 1 when any check fails, 2 on bad input):
* every ISR: measured cycles per event <= its budget;
* the ISR load U at the maximum encoder edge rate (both wheels at the motors' no-load speed:
  2 * no_load_rad_s / 2pi * encoder_ppr, about 21 700 edges/s) plus the other ISRs;
* every task: worst case = measured max cycles / (1 - U) (the ISRs steal a fraction U of the CPU
  while the task runs) <= budget, and no overrun counted during a recorded run;
* all tasks released together (every 100 ms the 20/25/50 ms periods coincide): the sum of the
  worst cases fits in the shortest period;
* CPU utilisation sum(C/T) + U <= the limit;
* at the design edge rate (200 000 edges/s) the encoder ISR alone still fits (U < 1).

Bad input (exit 2, with file, row/line and column or key): a run folder the run-format reader
refuses (host_tools/runfmt/: encoding, CSV structure, numbers, meta.json), a missing or
non-numeric timing column, a ddtiming/1 or fil.json file that is not UTF-8 JSON of the shape
above, an option outside its bounds, a --json file that cannot be written (checked before
anything is read).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
from dataclasses import dataclass

from host_tools import protocol as P

SATURATED_UNITS = 65535  # telemetry task times saturate at 65535 units of 16 cycles
EDGE_RATE_MAX = 1e8      # --edge-rate bound, edges/s (the design rate is 200 000)
ISR_CYCLES_MAX = 1e6     # --isr-cycles bound, cycles per edge
CYCLES_MAX = 1e12        # any cycle count or event rate in a ddtiming/1 file


class TimingInputError(ValueError):
    pass


@dataclass
class Row:
    check: str
    source: str
    budget: float
    worst: float
    unit: str
    ok: bool
    note: str = ""

    @property
    def margin(self) -> float:
        return self.budget - self.worst


def edge_rate_max(d: P.Definition, meta: dict | None = None) -> float:
    """Both wheels at the motors' no-load speed, in encoder edges per second."""
    motor = (meta or {}).get("motor", d.robot_defaults["motor"])
    ppr = (meta or {}).get("encoder_ppr", d.robot_defaults["encoder_ppr"])
    return 2 * motor["no_load_rad_s"] / (2 * math.pi) * ppr


def _read_json(path: str) -> object:
    """A JSON file (UTF-8, at most 64 levels deep) or TimingInputError with line and column."""
    from host_tools import runfmt

    try:
        text = runfmt.read_text(path)
    except runfmt.RunFormatError as exc:
        raise TimingInputError(str(exc)) from None
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise TimingInputError(f"{runfmt.display(path)}, line {exc.lineno}, character {exc.colno}: "
                               f"invalid JSON: {exc.msg}") from None
    except (RecursionError, ValueError) as exc:
        raise TimingInputError(f"{runfmt.display(path)}: invalid JSON: "
                               f"{'nested too deeply' if isinstance(exc, RecursionError) else exc}"
                               ) from None
    if not runfmt._json_depth_ok(doc, 64):
        raise TimingInputError(f"{runfmt.display(path)}: JSON nested more than 64 levels deep")
    return doc


def _num(path: str, obj, key: str, where: str, hi: float = CYCLES_MAX) -> float:
    v = obj.get(key) if isinstance(obj, dict) else None
    if (isinstance(v, bool) or not isinstance(v, (int, float))
            or (isinstance(v, float) and not math.isfinite(v)) or not 0 <= v <= hi):
        from host_tools.runfmt import _show, display
        raise TimingInputError(f"{display(path)}, key '{where}.{key}': must be a number in "
                               f"[0, {hi:g}], got {_show(v)}")
    return float(v)


def _mapping(path: str, obj, where: str) -> dict:
    if obj is None:
        return {}
    if not isinstance(obj, dict) or not all(isinstance(v, dict) for v in obj.values()):
        from host_tools.runfmt import display
        raise TimingInputError(f"{display(path)}, key '{where}': must be an object of objects")
    return obj


def load_sim(path: str) -> dict:
    from host_tools.runfmt import display

    sim = _read_json(path)
    if not isinstance(sim, dict) or sim.get("format") != "ddtiming/1":
        raise TimingInputError(f"{display(path)}, key 'format': must be \"ddtiming/1\"")
    for name, isr in _mapping(path, sim.get("isr"), "isr").items():
        isr["cycles_per_event"] = _num(path, isr, "cycles_per_event", f"isr.{name}")
    for name, task in _mapping(path, sim.get("tasks"), "tasks").items():
        task["max_cycles"] = _num(path, task, "max_cycles", f"tasks.{name}")
    other = sim.get("other_isr") or []
    if not isinstance(other, list):
        raise TimingInputError(f"{display(path)}, key 'other_isr': must be a list")
    for i, o in enumerate(other):
        o_cyc = _num(path, o, "cycles_per_event", f"other_isr[{i}]")
        o_rate = _num(path, o, "events_per_s", f"other_isr[{i}]")
        o["cycles_per_event"], o["events_per_s"] = o_cyc, o_rate
    if "f_cpu_hz" in sim:
        sim["f_cpu_hz"] = _num(path, sim, "f_cpu_hz", "")
    return sim


def sim_from_fil(path: str) -> dict:
    """The ddtiming/1 view of a firmware-in-the-loop fil.json (sim/fil/recorder.cpp)."""
    from host_tools.runfmt import display

    fil = _read_json(path)
    enc = fil.get("encoder_isr") if isinstance(fil, dict) else None
    tasks = fil.get("tasks") if isinstance(fil, dict) else None
    if not isinstance(enc, dict) or not isinstance(tasks, dict):
        raise TimingInputError(f"{display(path)}: fil.json lacks encoder_isr.max_cycles or "
                               "tasks.*.max_cycles")
    sim = {"format": "ddtiming/1", "source": "fil.json",
           "isr": {"encoder": {"cycles_per_event": _num(path, enc, "max_cycles", "encoder_isr")}},
           "tasks": {k: {"max_cycles": _num(path, v, "max_cycles", f"tasks.{k}")}
                     for k, v in tasks.items() if isinstance(v, dict) and "max_cycles" in v}}
    if not enc.get("calls"):
        del sim["isr"]  # no edge was driven: no ISR measurement
    return sim


def load_run_timing(run_dir: str, d: P.Definition) -> tuple[dict, dict]:
    """Per task {max_cycles, last_max, overruns_delta, overruns_total, saturated} and meta."""
    from host_tools import runfmt

    try:
        run = runfmt.load_run(run_dir, check_units=False, min_rows=1)
    except runfmt.RunFormatError as exc:
        raise TimingInputError(str(exc)) from None
    tel = run.telemetry
    tpath = os.path.join(run_dir, "telemetry.csv")
    cols = {f.name: f for f in d.by_name["Telemetry"].fields}
    out = {}
    for t in d.tasks():
        name = t["name"]
        need = [cols[f"{name}_max"].column, cols[f"{name}_last"].column, cols[f"{name}_overruns"].column]
        for c in need:
            if c not in tel:
                raise TimingInputError(f"{runfmt.display(tpath)}, line 1, column '{c}': missing (the task timing fields of the "
                                       "Telemetry message in protocol/protocol.json)")
            if tel[c].dtype == object:
                i = next(k for k, v in enumerate(tel[c]) if runfmt.parse_number(str(v)) is None
                         or not math.isfinite(runfmt.parse_number(str(v))))
                raise TimingInputError(f"{runfmt.display(tpath)}, row {i + 1} (line {i + 2}), "
                                       f"column '{c}': not a finite number: "
                                       f"{runfmt._show(tel[c][i])}")
        mx, last, ovr = (tel[c] for c in need)
        scale = cols[f"{name}_max"].scale or 1
        out[name] = {
            "max_cycles": float(max(mx.max(), last.max())),
            "saturated": bool(mx.max() >= SATURATED_UNITS * scale),
            "overruns_delta": int(ovr[-1] - ovr[0]) if ovr.size else 0,
            "overruns_total": int(ovr.max()) if ovr.size else 0,
        }
    period = run.meta.get("periods_s", {}).get("telemetry")
    import numpy as np
    dt = np.diff(run.t_s)
    out["_telemetry_dt"] = {"median": float(np.median(dt)) if dt.size else None,
                            "max": float(dt.max()) if dt.size else None, "period": period,
                            "frames": int(run.t_s.size)}
    return out, run.meta


def check(d: P.Definition, runs: list[str], sims: list[str], edge_rate: float | None = None,
          isr_cycles: float | None = None, use_fil: bool = True) -> tuple[list[Row], list[str]]:
    tim = d.timing
    f_cpu = float(tim["f_cpu_hz"])
    tasks = {t["name"]: t for t in d.tasks()}
    rows: list[Row] = []
    notes: list[str] = []
    sim_data = [(os.path.basename(p), load_sim(p)) for p in sims]
    run_data = []
    for r in runs:
        tm, meta = load_run_timing(r, d)
        name = os.path.basename(os.path.normpath(r))
        run_data.append((name, tm, meta))
        fil = os.path.join(r, "fil.json")
        if use_fil and os.path.isfile(fil):
            sim_data.append((f"{name}/fil.json", sim_from_fil(fil)))
    if not sim_data and not run_data:
        raise TimingInputError("nothing to check: give --run RUN_DIR and/or --sim SIM.json")

    # ---- ISRs
    meta0 = run_data[0][2] if run_data else None
    rate = edge_rate if edge_rate is not None else edge_rate_max(d, meta0)
    isr_budget = {i["name"]: i["budget_cycles_per_event"] for i in tim["isr"]}
    enc_cycles = isr_cycles
    enc_src = "--isr-cycles" if isr_cycles is not None else None
    other_load = 0.0
    for src, sim in sim_data:
        fc = sim.get("f_cpu_hz", f_cpu)
        if fc != f_cpu:
            raise TimingInputError(f"{src}: f_cpu_hz {fc} differs from protocol.json timing.f_cpu_hz {f_cpu}")
        for name, isr in (sim.get("isr") or {}).items():
            if name not in isr_budget:
                notes.append(f"{src}: ISR '{name}' has no budget in protocol.json; not checked")
                continue
            c = isr["cycles_per_event"]
            rows.append(Row(f"isr {name} per edge", src, isr_budget[name], c, "cycles", c <= isr_budget[name]))
            if name == "encoder" and (enc_cycles is None or c > enc_cycles):
                enc_cycles, enc_src = c, src
        for o in sim.get("other_isr") or []:
            other_load += o["cycles_per_event"] * o["events_per_s"] / f_cpu
    u_isr = 0.0
    if enc_cycles is not None:
        u_enc = enc_cycles * rate / f_cpu
        u_isr = u_enc + other_load
        rows.append(Row(f"isr load at {rate:,.0f} edges/s", enc_src, 1.0, u_isr, "cpu", u_isr < 1.0,
                        f"encoder {100 * u_enc:.2f} % + other ISRs {100 * other_load:.2f} %"))
        design = tim.get("encoder_edges_per_s_design")
        if design:
            u_d = enc_cycles * design / f_cpu
            rows.append(Row(f"isr load at design {design:,.0f} edges/s", enc_src, 1.0, u_d, "cpu", u_d < 1.0,
                            "encoder ISR alone must keep up"))
    else:
        notes.append("no encoder ISR measurement (--sim with isr.encoder or --isr-cycles): task worst "
                     "cases are NOT inflated by ISR preemption")
    inflate = 1.0 / (1.0 - u_isr) if u_isr < 1.0 else math.inf

    # ---- tasks, per source
    def task_rows(src: str, measured: dict[str, float], extra: dict[str, dict] | None = None):
        worst = {}
        for name, t in tasks.items():
            if name not in measured:
                notes.append(f"{src}: no measurement for task '{name}'")
                continue
            w = measured[name] * inflate
            worst[name] = w
            note = f"measured {measured[name]:,.0f} x {inflate:.3f} (ISR load)" if u_isr else ""
            ok = w <= t["budget_cycles"]
            if extra and name in extra:
                e = extra[name]
                if e["saturated"]:
                    note += "; time saturated (>= 65.5 ms)"
                    ok = False
                if e["overruns_delta"] > 0:
                    note += f"; {e['overruns_delta']} overruns during the run"
                    ok = False
            rows.append(Row(f"task {name} ({t['period_us'] / 1000:g} ms)", src, t["budget_cycles"], w,
                            "cycles", ok, note.strip("; ")))
        if len(worst) == len(tasks):
            tmin = min(t["period_us"] for t in tasks.values()) * f_cpu / 1e6
            s = sum(worst.values())
            rows.append(Row("all tasks released together", src, tmin, s, "cycles", s <= tmin,
                            "sum of worst cases within the shortest period"))
            util = sum(worst[n] / (t["period_us"] * f_cpu / 1e6) for n, t in tasks.items()) * (1 - u_isr) + u_isr
            lim = tim.get("cpu_utilisation_limit", 1.0)
            rows.append(Row("cpu utilisation", src, lim, util, "cpu", util <= lim, "tasks + ISRs"))

    for src, sim in sim_data:
        if sim.get("tasks"):
            task_rows(src, {n: v["max_cycles"] for n, v in sim["tasks"].items()})
    for src, tm, meta in run_data:
        task_rows(src, {n: v["max_cycles"] for n, v in tm.items() if not n.startswith("_")},
                  {n: v for n, v in tm.items() if not n.startswith("_")})
        dt = tm["_telemetry_dt"]
        if dt["median"] is not None and dt["period"]:
            notes.append(f"{src}: {dt['frames']} frames, telemetry interval median {dt['median'] * 1000:.2f} ms "
                         f"(period {dt['period'] * 1000:g} ms), max {dt['max'] * 1000:.1f} ms")
    return rows, notes


def render(rows: list[Row], notes: list[str]) -> str:
    head = f"{'check':34s} {'source':22s} {'budget':>14s} {'worst':>14s} {'margin':>16s}  result"
    lines = [head, "-" * len(head)]

    def fmt(v, unit):
        if unit == "cpu":
            return f"{100 * v:.2f} %"
        return "inf" if math.isinf(v) else f"{v:,.0f}"
    for r in rows:
        if r.unit == "cpu":
            margin = f"{100 * r.margin:+.2f} pt"
        else:
            margin = ("-inf" if math.isinf(r.worst) else
                      f"{r.margin:+,.0f} ({100 * r.margin / r.budget:+.0f}%)" if r.budget else f"{r.margin:+,.0f}")
        lines.append(f"{r.check:34s} {r.source[:22]:22s} {fmt(r.budget, r.unit):>14s} {fmt(r.worst, r.unit):>14s} "
                     f"{margin:>16s}  {'ok' if r.ok else 'OVER BUDGET'}" + (f"  {r.note}" if r.note else ""))
    for n in notes:
        lines.append(f"note: {n}")
    return "\n".join(lines)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--run", action="append", default=[], metavar="RUN_DIR",
                   help="recorded run whose telemetry carries the task timing fields (repeatable)")
    p.add_argument("--sim", action="append", default=[], metavar="SIM_JSON",
                   help="simavr measurements, format ddtiming/1 (repeatable; see the module doc)")
    p.add_argument("--edge-rate", type=float, help="encoder edges/s for the ISR load (default: both wheels "
                   "at the no-load speed, from meta.json or protocol.json)")
    p.add_argument("--isr-cycles", type=float, help="encoder ISR cycles per edge, when no --sim gives it")
    p.add_argument("--no-fil", action="store_true", help="ignore fil.json in --run folders")
    p.add_argument("--json", metavar="OUT", help="also write the rows as JSON")


def _check_options(args: argparse.Namespace) -> str | None:
    if args.edge_rate is not None and not (math.isfinite(args.edge_rate)
                                           and 0 < args.edge_rate <= EDGE_RATE_MAX):
        return f"--edge-rate {args.edge_rate:g} must be in (0, {EDGE_RATE_MAX:g}] edges/s"
    if args.isr_cycles is not None and not (math.isfinite(args.isr_cycles)
                                            and 0 < args.isr_cycles <= ISR_CYCLES_MAX):
        return f"--isr-cycles {args.isr_cycles:g} must be in (0, {ISR_CYCLES_MAX:g}]"
    if len(args.run) + len(args.sim) > 1000:
        return "at most 1000 --run and --sim sources"
    if args.json:
        from host_tools.runfmt import display
        if os.path.isdir(args.json):
            return f"--json {display(args.json)} is a folder"
        existed = os.path.exists(args.json)
        try:
            with open(args.json, "a"):
                pass
        except OSError as exc:
            return f"--json {display(args.json)} cannot be written: {exc.strerror or exc}"
        if not existed:
            os.remove(args.json)
    return None


def main(args: argparse.Namespace) -> int:
    d = P.definition()
    problem = _check_options(args)
    if problem:
        print(f"error: {problem}", file=sys.stderr)
        return 2
    try:
        rows, notes = check(d, args.run, args.sim, args.edge_rate, args.isr_cycles, not args.no_fil)
    except TimingInputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(render(rows, notes))
    if args.json:
        try:
            with open(args.json, "w", encoding="utf-8", errors="backslashreplace") as fh:
                json.dump({"rows": [dict(r.__dict__, margin=r.margin) for r in rows],
                           "notes": notes}, fh, indent=2)
        except OSError as exc:
            print(f"error: cannot write --json {args.json!r}: {exc.strerror or exc}",
                  file=sys.stderr)
            return 1
    bad = [r for r in rows if not r.ok]
    if bad:
        print(f"\nFAILED: {len(bad)} check(s) over budget: " + ", ".join(f"{r.check} [{r.source}]" for r in bad))
        return 1
    print(f"\nall {len(rows)} checks within budget")
    return 0
