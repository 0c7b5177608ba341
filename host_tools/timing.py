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
import logging
import math
import os
import tempfile
from dataclasses import dataclass

from host_tools import protocol as P
from host_tools._stdio import out

log = logging.getLogger(__name__)

SATURATED_UNITS = 65535  # telemetry task times saturate at 65535 units of 16 cycles
EDGE_RATE_MAX = 1e8      # --edge-rate bound, edges/s (the design rate is 200 000)
ISR_CYCLES_MAX = 1e6     # --isr-cycles bound, cycles per edge
CYCLES_MAX = 1e12        # any cycle count or event rate in a ddtiming/1 file
JSON_MAX_BYTES = 16 << 20  # a ddtiming/1 or fil.json file (a few KB in practice)


class TimingInputError(ValueError):
    pass


@dataclass
class Row:
    check: str
    source: str
    budget: float
    worst: float | None  # None: no bound (the ISRs leave no time for the task)
    unit: str            # "cycles", or "cpu" (a fraction of the CPU, shown in %)
    ok: bool
    note: str = ""

    @property
    def margin(self) -> float | None:
        return None if self.worst is None else self.budget - self.worst


def edge_rate_max(d: P.Definition, meta: dict | None = None) -> float:
    """Both wheels at the motors' no-load speed, in encoder edges per second."""
    motor = (meta or {}).get("motor", d.robot_defaults["motor"])
    ppr = (meta or {}).get("encoder_ppr", d.robot_defaults["encoder_ppr"])
    return 2 * motor["no_load_rad_s"] / (2 * math.pi) * ppr


def _read_json(path: str) -> object:
    """A JSON file (UTF-8, at most 64 levels deep) or TimingInputError with line and column."""
    from host_tools import runfmt

    try:
        text = runfmt.read_text(path, limit=JSON_MAX_BYTES)
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
    if not runfmt.json_depth_ok(doc, 64):
        raise TimingInputError(f"{runfmt.display(path)}: JSON nested more than 64 levels deep")
    return doc


def _num(path: str, obj, key: str, where: str, hi: float = CYCLES_MAX) -> float:
    v = obj.get(key) if isinstance(obj, dict) else None
    if (isinstance(v, bool) or not isinstance(v, (int, float))
            or (isinstance(v, float) and not math.isfinite(v)) or not 0 <= v <= hi):
        from host_tools.runfmt import show_value, display
        raise TimingInputError(f"{display(path)}, key '{where}.{key}': must be a number in "
                               f"[0, {hi:g}], got {show_value(v)}")
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
    other = _fil_other_isrs(path, fil, enc)
    if other:
        sim["other_isr"] = [other]
    if not enc.get("calls"):
        del sim["isr"]  # no edge was driven: no ISR measurement
    return sim


def _fil_other_isrs(path: str, fil: dict, enc: dict) -> dict | None:
    """Every ISR fil.json measured but the encoder's (the scheduler tick, the UART, the ADC,
    ...), as one load: the sum over vectors of calls x mean cycles per simulated second, less
    the encoder ISR's own calls x mean cycles."""
    vectors = fil.get("isr_cycles")
    if not isinstance(vectors, dict) or not vectors or "sim_s" not in fil:
        return None
    sim_s = _num(path, fil, "sim_s", "")
    if sim_s <= 0:
        return None
    calls = cycles = 0.0
    for v, st in vectors.items():
        n = _num(path, st, "calls", f"isr_cycles.{v}")
        calls += n
        cycles += n * _num(path, st, "mean", f"isr_cycles.{v}")
    if enc.get("calls"):
        n = _num(path, enc, "calls", "encoder_isr")
        calls -= n
        cycles -= n * _num(path, enc, "mean_cycles", "encoder_isr")
    if calls <= 0 or cycles <= 0:
        return None
    return {"name": f"other vectors ({len(vectors)} measured, encoder's excluded)",
            "cycles_per_event": cycles / calls, "events_per_s": calls / sim_s}


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
    boot_col = cols["boot_count"].column if "boot_count" in cols else None
    boots = tel.get(boot_col) if boot_col else None
    if boots is not None and boots.dtype == object:
        boots = None  # a text column: no boot segments, every decrease counts as a wrap
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
                                       f"{runfmt.show_value(tel[c][i])}")
        mx, last, ovr = (tel[c] for c in need)
        scale = cols[f"{name}_max"].scale or 1
        out[name] = {
            "max_cycles": float(max(mx.max(), last.max())),
            "saturated": bool(mx.max() >= SATURATED_UNITS * scale),
            "overruns_delta": overrun_increments(ovr, boots),
            "overruns_total": int(ovr.max()) if ovr.size else 0,
        }
    period = run.meta.get("periods_s", {}).get("telemetry")
    import numpy as np
    dt = np.diff(run.t_s)
    out["_telemetry_dt"] = {"median": float(np.median(dt)) if dt.size else None,
                            "max": float(dt.max()) if dt.size else None, "period": period,
                            "frames": int(run.t_s.size)}
    return out, run.meta


def overrun_increments(ovr, boots=None, bits: int = 16) -> int:
    """Overruns counted during a recording: the sum of the counter's increments row to row.
    Within one boot a decrease is the counter wrapping at 2**bits (never a smaller count);
    where ``boots`` (the telemetry's boot_count) changes, the board restarted and its counter
    with it: the new boot's first value is all new."""
    import numpy as np

    v = np.asarray(ovr, dtype=np.int64)
    if v.size < 2:
        return 0
    step = np.mod(np.diff(v), 1 << bits)
    if boots is not None:
        b = np.asarray(boots)
        restart = b[1:] != b[:-1]
        step = np.where(restart, v[1:], step)
    return int(step.sum())


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

    # ---- ISRs: one row per ISR, the worst source
    meta0 = run_data[0][2] if run_data else None
    rate = edge_rate if edge_rate is not None else edge_rate_max(d, meta0)
    isr_budget = {i["name"]: i["budget_cycles_per_event"] for i in tim["isr"]}
    isr_worst: dict[str, tuple[float, str]] = {}
    if isr_cycles is not None:
        isr_worst["encoder"] = (isr_cycles, "--isr-cycles")
    other_load, other_src = 0.0, ""
    for src, sim in sim_data:
        fc = sim.get("f_cpu_hz", f_cpu)
        if fc != f_cpu:
            raise TimingInputError(f"{src}: f_cpu_hz {fc} differs from protocol.json timing.f_cpu_hz {f_cpu}")
        for name, isr in (sim.get("isr") or {}).items():
            if name not in isr_budget:
                notes.append(f"{src}: ISR '{name}' has no budget in protocol.json; not checked")
                continue
            c = isr["cycles_per_event"]
            if name not in isr_worst or c > isr_worst[name][0]:
                isr_worst[name] = (c, src)
        load = sum(o["cycles_per_event"] * o["events_per_s"] / f_cpu for o in sim.get("other_isr") or [])
        if load > other_load:  # sources describe the same firmware: the heaviest counts
            other_load, other_src = load, src
            for o in sim.get("other_isr") or []:
                notes.append(f"{src}: ISR {o['name']}: {o['events_per_s']:,.0f} /s x "
                             f"{o['cycles_per_event']:,.1f} cycles = "
                             f"{100 * o['cycles_per_event'] * o['events_per_s'] / f_cpu:.2f} % of the CPU")
    for name, (c, src) in isr_worst.items():
        if name in isr_budget:
            rows.append(Row(f"isr {name} per edge", src, isr_budget[name], c, "cycles", c <= isr_budget[name]))
    u_isr = other_load
    if "encoder" in isr_worst:
        enc_cycles, enc_src = isr_worst["encoder"]
        u_enc = enc_cycles * rate / f_cpu
        u_isr = u_enc + other_load
        src = enc_src if not other_src or other_src == enc_src else f"{enc_src} + {other_src}"
        rows.append(Row(f"isr load at {rate:,.0f} edges/s", src, 1.0, u_isr, "cpu", u_isr < 1.0,
                        f"encoder {100 * u_enc:.2f} % + other ISRs {100 * other_load:.2f} %"))
        design = tim.get("encoder_edges_per_s_design")
        if design:
            u_d = enc_cycles * design / f_cpu
            rows.append(Row(f"isr load at design {design:,.0f} edges/s", enc_src, 1.0, u_d, "cpu", u_d < 1.0,
                            "encoder ISR alone must keep up"))
    else:
        notes.append("no encoder ISR measurement (--sim with isr.encoder or --isr-cycles): task worst "
                     "cases are NOT inflated by ISR preemption")
    # the ISRs steal a fraction u_isr of the CPU while a task runs; at u_isr >= 1 no task
    # ever finishes: its worst case has no bound (reported as such, never as infinity)
    bounded = u_isr < 1.0
    inflate = 1.0 / (1.0 - u_isr) if bounded else None

    # ---- tasks: one row per task, the worst of every source
    per_task: dict[str, list[tuple[float, str, dict | None]]] = {n: [] for n in tasks}
    for src, sim in sim_data:
        for n, v in (sim.get("tasks") or {}).items():
            if n in per_task:
                per_task[n].append((v["max_cycles"], src, None))
    for src, tm, meta in run_data:
        for n, v in tm.items():
            if n in per_task:
                per_task[n].append((v["max_cycles"], src, v))
        dt = tm["_telemetry_dt"]
        if dt["median"] is not None and dt["period"]:
            notes.append(f"{src}: {dt['frames']} frames, telemetry interval median {dt['median'] * 1000:.2f} ms "
                         f"(period {dt['period'] * 1000:g} ms), max {dt['max'] * 1000:.1f} ms")
    measured: dict[str, float] = {}
    for name, t in tasks.items():
        if not per_task[name]:
            notes.append(f"no measurement for task '{name}'")
            continue
        c, src, _ = max(per_task[name], key=lambda m: m[0])
        measured[name] = c
        w = c * inflate if bounded else None
        parts = []
        if u_isr and bounded:
            parts.append(f"measured {c:,.0f} cycles x {inflate:.3f} (ISR load)")
        elif not bounded:
            parts.append(f"measured {c:,.0f} cycles; unbounded: the ISRs take the whole CPU")
        if len(per_task[name]) > 1:
            parts.append("worst of " + ", ".join(f"{s_} {m:,.0f}" for m, s_, _ in per_task[name]))
        ok = bounded and w <= t["budget_cycles"]
        for _, s_, e in per_task[name]:
            if e is None:
                continue
            if e["saturated"]:
                parts.append(f"{s_}: time saturated (>= 65.5 ms)")
                ok = False
            if e["overruns_delta"] > 0:
                parts.append(f"{s_}: {e['overruns_delta']} overruns during the run")
                ok = False
        rows.append(Row(f"task {name} ({t['period_us'] / 1000:g} ms)", src, t["budget_cycles"], w,
                        "cycles", ok, "; ".join(parts)))
    if len(measured) == len(tasks):
        src = "all sources"
        tmin = min(t["period_us"] for t in tasks.values()) * f_cpu / 1e6
        s_ = sum(measured.values()) * inflate if bounded else None
        rows.append(Row("all tasks released together", src, tmin, s_, "cycles",
                        bounded and s_ <= tmin, "sum of worst cases within the shortest period"))
        # demand: every task's measured cycles per period plus the ISRs' share
        util = sum(measured[n] / (t["period_us"] * f_cpu / 1e6) for n, t in tasks.items()) + u_isr
        lim = tim.get("cpu_utilisation_limit", 1.0)
        rows.append(Row("cpu utilisation", src, lim, util, "cpu", util <= lim, "tasks + ISRs"))
    for r in rows:
        for v in (r.budget, r.worst):
            if v is not None and not math.isfinite(v):
                raise TimingInputError(f"{r.check} [{r.source}]: the figure {v} is not finite; "
                                       "the inputs are out of any physical range")
    return rows, notes


def render(rows: list[Row], notes: list[str]) -> str:
    head = (f"{'check':34s} {'source':22s} {'budget':>16s} {'worst':>16s} {'margin':>18s}  result")
    lines = [head, "-" * len(head)]

    def fmt(v, unit):
        if v is None:
            return "unbounded"
        return f"{100 * v:.2f} % CPU" if unit == "cpu" else f"{v:,.0f} cycles"
    for r in rows:
        if r.worst is None:
            margin = "none"
        elif r.unit == "cpu":
            margin = f"{100 * r.margin:+.2f} pt"
        else:
            margin = (f"{r.margin:+,.0f} ({100 * r.margin / r.budget:+.0f}%)" if r.budget
                      else f"{r.margin:+,.0f}")
        lines.append(f"{r.check:34s} {r.source[:22]:22s} {fmt(r.budget, r.unit):>16s} "
                     f"{fmt(r.worst, r.unit):>16s} {margin:>18s}  {'ok' if r.ok else 'OVER BUDGET'}"
                     + (f"  {r.note}" if r.note else ""))
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
        return _check_json_out(args)
    return None


def _check_json_out(args: argparse.Namespace) -> str | None:
    """--json never names an input: a --sim file or a file a --run folder already holds
    (meta.json, telemetry.csv, fil.json, ...), also through a link; its folder must take a new
    file (tested by creating one exclusively and removing it)."""
    from host_tools.runfmt import display

    shown = display(args.json)
    if os.path.isdir(args.json):
        return f"--json {shown} is a folder"
    target = os.path.realpath(args.json)
    for r in args.run:
        inside = os.path.realpath(r) + os.sep
        if target.startswith(inside) and os.path.lexists(target):
            return f"--json {shown} is a file of the run {display(r)}; refusing to overwrite it"
    for f in args.sim:
        if os.path.exists(f) and os.path.realpath(f) == target:
            return f"--json {shown} is the --sim input {display(f)}; refusing to overwrite it"
    folder = os.path.dirname(os.path.abspath(args.json))
    try:
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".timing-check-"):
            pass
    except OSError as exc:
        return f"--json {shown} cannot be written: {exc.strerror or exc}"
    return None


def main(args: argparse.Namespace) -> int:
    d = P.definition()
    problem = _check_options(args)
    if problem:
        log.error("%s", problem)
        return 2
    try:
        rows, notes = check(d, args.run, args.sim, args.edge_rate, args.isr_cycles, not args.no_fil)
    except TimingInputError as exc:
        log.error("%s", exc)
        return 2
    if args.json:
        try:
            from host_tools.runfmt import write_atomic
            doc = {"rows": [dict(r.__dict__, margin=r.margin) for r in rows], "notes": notes}
            write_atomic(args.json, json.dumps(doc, indent=2, allow_nan=False) + "\n")
        except OSError as exc:
            log.error(f"cannot write --json {args.json!r}: {exc.strerror or exc}")
            return 1
    out(render(rows, notes))
    bad = [r for r in rows if not r.ok]
    if bad:
        out(f"\nFAILED: {len(bad)} check(s) over budget: " + ", ".join(f"{r.check} [{r.source}]" for r in bad))
        return 1
    out(f"\nall {len(rows)} checks within budget")
    return 0
