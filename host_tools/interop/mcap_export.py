"""``ddrobot export RUN_DIR [--report OUT_DIR] --out FILE.mcap``: a run folder (and what the
analyzer found in it) as one MCAP file that Foxglove opens.

Topics (:data:`host_tools.interop.messages.TOPICS`): ``/telemetry`` (every column of
telemetry.csv, JSON), ``/odometry/pose`` and ``/odometry/tf`` (the robot's odometry),
``/groundtruth/pose`` and ``/groundtruth/tf`` (groundtruth.csv, when the run has one), and
with ``--report`` the analyzer's findings for this run from report.json: ``/analysis/summary``,
``/analysis/mismatch`` (one message per window), ``/analysis/mismatch_active`` (per frame, 1
inside a window) and ``/analysis/localization``.  All on the run's board time.

With ``--report``, the analyzer's per-sample series of this run (OUT_DIR/series/<run>.csv) too:
one topic per channel, ``/analysis/series/<channel>`` (recording, nominal and updated replay,
residuals, noise band, replay window, in a mismatch window), on the same timeline.

Exit codes: 0 done, 2 bad input (a run or report that cannot be read, with the file and place;
--out not writable), 1 the MCAP could not be written.
"""
from __future__ import annotations

import argparse
import json
import logging
import math
import os
import types
from typing import Any

import numpy as np

from host_tools import runfmt
from host_tools.interop import _cli
from host_tools.interop import messages as M

log = logging.getLogger(__name__)


class ExportError(Exception):
    """Bad input: the message says what and where."""


def _report_for_run(report_dir: str, run: runfmt.Run) -> dict:
    """report.json of ``report_dir`` with 'mismatch' and 'localization' kept for this run only
    (the analyzer's label of the run is recomputed from the report's run list)."""
    path = os.path.join(report_dir, "report.json")
    text = _cli.read_text(path, ExportError)
    try:
        rep = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ExportError(f"{runfmt.display(path)}: line {exc.lineno}, column {exc.colno}: "
                          f"not JSON: {exc.msg}") from None
    if not isinstance(rep, dict) or rep.get("format") != "mismatch-report/1":
        raise ExportError(f"{runfmt.display(path)}: not a mismatch report (format "
                          "mismatch-report/1)")
    paths = [str(p) for p in rep.get("runs", [])]
    fake = [types.SimpleNamespace(path=p, label=None) for p in paths]
    runfmt.label_runs(fake)
    mine = os.path.realpath(run.path)
    idx = [i for i, p in enumerate(paths) if os.path.realpath(p) == mine]
    if not idx:  # the analysis ran from another folder: match by folder name
        base = os.path.basename(os.path.normpath(run.path))
        idx = [i for i, p in enumerate(paths) if os.path.basename(os.path.normpath(p)) == base]
    if len(idx) != 1:
        listed = ", ".join(paths) or "none"
        raise ExportError(f"{runfmt.display(path)}: the run {runfmt.display(run.path)} is not "
                          f"one of the report's runs ({listed})")
    label = fake[idx[0]].label
    rep = dict(rep)
    rep["label"] = label
    rep["run_index"] = idx[0]
    for key, need in (("mismatch", ("channel", "t_start_s", "t_end_s")),
                      ("localization", ("t_start_s", "t_end_s"))):
        entries = rep.get(key) or []
        if not isinstance(entries, list):
            raise ExportError(f"{runfmt.display(path)}: '{key}' is not a list")
        for i, m in enumerate(entries):
            bad = [k for k in need if not isinstance(m, dict) or k not in m
                   or (k != "channel" and not _finite(m[k]))]
            if bad:
                raise ExportError(f"{runfmt.display(path)}: {key}[{i}]: {bad[0]} missing or "
                                  "not a finite number")
        rep[key] = [m for m in entries if m.get("run") == label]
    return rep


def _finite(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _summary(rep: dict) -> dict:
    """The report's findings as one flat JSON message."""
    sel = []
    std = {c.get("effect"): c.get("param_std", {}) for c in rep.get("candidates") or []}
    for s in rep.get("selected") or []:
        sel.append({"effect": s.get("effect"), "params": s.get("params", {}),
                    "param_std": std.get(s.get("effect"), {}),
                    "equivalent": s.get("equivalent", [])})
    return {"run": rep["label"], "verdict": rep.get("verdict"), "selected": sel,
            "fit": rep.get("fit", {}), "mismatch_windows": len(rep["mismatch"])}


class _Out:
    """An mcap.writer.Writer with one channel per topic, registered on first use."""

    def __init__(self, fh):
        from mcap.writer import Writer
        self.w = Writer(fh)
        self.w.start(profile="", library="ddrobot export")
        self.channels: dict[str, int] = {}
        self.counts: dict[str, int] = {}

    def channel(self, topic: str, fields: dict | None = None) -> int:
        if topic not in self.channels:
            name, enc, data = M.schema_for(topic, fields)
            sid = self.w.register_schema(name=name, encoding=enc, data=data)
            self.channels[topic] = self.w.register_channel(
                topic=topic, message_encoding=M.message_encoding(enc), schema_id=sid,
                metadata={"description": M.topic_info(topic).what})
            self.counts[topic] = 0
        return self.channels[topic]

    def add(self, topic: str, t_s: float, data: bytes, fields: dict | None = None) -> None:
        cid = self.channel(topic, fields)
        n = M.ns(t_s)
        self.w.add_message(channel_id=cid, log_time=n, publish_time=n, data=data,
                           sequence=self.counts[topic])
        self.counts[topic] += 1

    def finish(self) -> None:
        self.w.finish()


Event = tuple  # (t_s, order, topic, data, JSON fields or None): one message to write

WINDOW_FIELDS = {"run": "string", "channel": "string", "t_start_s": "number", "t_end_s": "number",
                 "rms": "number", "noise_floor": "number", "regime": "string", "replay": "string"}
SPAN_FIELDS = {"run": "string", "t_start_s": "number", "t_end_s": "number",
               "peak_noise_floors": "number", "channels": "array", "strong": "boolean",
               "rms_after_update_noise_floors": "number"}
SUMMARY_FIELDS = {"run": "string", "verdict": "string", "selected": "array", "fit": "object",
                  "mismatch_windows": "integer"}


def _run_events(run: runfmt.Run) -> list[Event]:
    """Telemetry rows, odometry and ground-truth poses and transforms."""
    tel = run.telemetry
    t = tel["t_s"]
    fields = {c: "number" for c in tel}
    cols = {c: v.tolist() for c, v in tel.items()}
    ev: list[Event] = []
    for i in range(t.size):
        ti = float(t[i])
        x, y, phi = (cols[k][i] for k in ("x_odo_m", "y_odo_m", "phi_odo_rad"))
        ev.append((ti, 0, "/telemetry", M.json_message({c: v[i] for c, v in cols.items()}),
                   fields))
        ev.append((ti, 1, "/odometry/pose", M.pose_in_frame(ti, x, y, phi), None))
        ev.append((ti, 2, "/odometry/tf", M.frame_transform(ti, M.BASE_ODO, x, y, phi), None))
    gt = run.groundtruth
    if gt is not None:
        phi_gt = gt.get("phi_rad")
        for i in range(gt["t_s"].size):
            tg, x, y = float(gt["t_s"][i]), float(gt["x_m"][i]), float(gt["y_m"][i])
            phi = float(phi_gt[i]) if phi_gt is not None else float("nan")
            ev.append((tg, 3, "/groundtruth/pose", M.pose_in_frame(tg, x, y, phi), None))
            ev.append((tg, 4, "/groundtruth/tf", M.frame_transform(tg, M.BASE_GT, x, y, phi),
                       None))
    return ev


def _report_events(rep: dict, t: np.ndarray) -> list[Event]:
    """The report's findings for this run: summary, windows, per-frame flags, spans."""
    ev: list[Event] = [(float(t[0]) if t.size else 0.0, 5, "/analysis/summary",
                        M.json_message(_summary(rep)), SUMMARY_FIELDS)]
    wins = rep["mismatch"]
    for m in wins:
        ev.append((max(m["t_start_s"], 0.0), 6, "/analysis/mismatch",
                   M.json_message({k: m.get(k) for k in WINDOW_FIELDS}), WINDOW_FIELDS))
    chans = sorted({m["channel"] for m in wins})
    flags_fields = {c: "integer" for c in chans + ["any"]}
    for ti in t.tolist():
        act = {c: int(any(m["channel"] == c and m["t_start_s"] <= ti <= m["t_end_s"]
                          for m in wins)) for c in chans}
        act["any"] = int(any(act.values()))
        ev.append((ti, 7, "/analysis/mismatch_active", M.json_message(act), flags_fields))
    for m in rep["localization"]:
        ev.append((max(m["t_start_s"], 0.0), 8, "/analysis/localization",
                   M.json_message({k: m.get(k) for k in SPAN_FIELDS}), SPAN_FIELDS))
    return ev


SERIES_NUMBERS = ("recording", "nominal", "updated", "residual_nominal", "residual_updated",
                  "noise_floor", "replay_uncertainty", "band")
SERIES_FIELDS = {"replay": "string", **{k: "number" for k in SERIES_NUMBERS},
                 "replay_window": "integer", "in_mismatch_window": "integer"}


def _series_file(report_dir: str, rep: dict) -> str | None:
    """This run's series/<run>.csv (report.json 'series', in the order of 'runs'), or None when
    the report has none (an analyzer that wrote no series)."""
    files = rep.get("series")
    if not isinstance(files, list) or len(files) != len(rep.get("runs") or []):
        return None
    name = files[rep["run_index"]]
    parts = name.split("/") if isinstance(name, str) else []
    if len(parts) != 2 or parts[0] != "series" or parts[1] in ("", ".", ".."):
        raise ExportError(f"{runfmt.display(os.path.join(report_dir, 'report.json'))}: "
                          f"series[{rep['run_index']}] is not series/<name>")
    return os.path.join(report_dir, *parts)


def _series_events(path: str) -> list[Event]:
    """One message per row of a series CSV, on topic /analysis/series/<channel>."""
    import csv
    shown = runfmt.display(path)
    text = _cli.read_text(path, ExportError)
    rows = csv.reader(text.splitlines())
    header = next(rows, None)
    need = ("channel", "t_s", *SERIES_FIELDS)
    if header is None or any(k not in header for k in need):
        miss = [k for k in need if header is None or k not in header]
        raise ExportError(f"{shown}: line 1: column {miss[0]} missing")
    col = {k: header.index(k) for k in need}
    ev: list[Event] = []
    for row_no, cells in enumerate(rows, 1):
        if len(cells) != len(header):
            raise ExportError(f"{shown}: row {row_no} (line {row_no + 1}): {len(cells)} cells, "
                              f"the header has {len(header)}")
        try:
            t = float(cells[col["t_s"]])
            msg = {"replay": cells[col["replay"]]}
            for k in SERIES_NUMBERS:
                v = cells[col[k]]
                msg[k] = float(v) if v != "" else None
            for k in ("replay_window", "in_mismatch_window"):
                msg[k] = int(cells[col[k]])
        except ValueError as exc:
            raise ExportError(f"{shown}: row {row_no} (line {row_no + 1}): not a number: "
                              f"{exc}") from None
        if not (_finite(t) and t >= 0) or not cells[col["channel"]]:
            raise ExportError(f"{shown}: row {row_no} (line {row_no + 1}), column t_s/channel: "
                              "a time of 0 s or later and a channel name are needed")
        ev.append((t, 9, M.SERIES_PREFIX + cells[col["channel"]], M.json_message(msg),
                   SERIES_FIELDS))
    return ev


def export(run_dir: str, out: str, report_dir: str | None = None) -> dict[str, int]:
    """Write ``out`` (MCAP) from the run folder ``run_dir`` and, optionally, the analyzer's
    ``report_dir``.  Returns the message count per topic.  ExportError / RunFormatError on bad
    input (nothing written); OSError when ``out`` cannot be written."""
    run = runfmt.load_run(run_dir)
    rep = _report_for_run(report_dir, run) if report_dir is not None else None
    t = np.asarray(run.telemetry["t_s"], dtype=float)
    firsts = [t[:1]] + ([run.groundtruth["t_s"][:1]] if run.groundtruth is not None else [])
    if any(a.size and a[0] < 0 for a in firsts):
        raise ExportError(f"{runfmt.display(run.path)}: times before 0 s cannot be MCAP log "
                          "times")
    events = _run_events(run) + (_report_events(rep, t) if rep is not None else [])
    series = _series_file(report_dir, rep) if rep is not None else None
    if series is not None:
        events += _series_events(series)
    events.sort(key=lambda e: (e[0], e[1]))
    tmp = out + ".part"
    try:
        with open(tmp, "wb") as fh:
            o = _Out(fh)
            for tt, _, topic, data, f in events:
                o.add(topic, tt, data, f)
            o.finish()
        os.replace(tmp, out)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise
    if rep is not None and series is None:
        log.info("the report lists no per-sample series for this run (an analyzer before "
                 "series/<run>.csv): exported its windows, verdict and fitted parameters only")
    return dict(o.counts)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.description = __doc__.split("\n\n")[0].split(": ", 1)[1].replace("``", "")
    p.epilog = ("topics: " + "; ".join(f"{t.name} ({t.schema})" for t in M.TOPICS.values())
                + ". Open FILE.mcap in Foxglove (File > Open local file). exit status: 0 done, "
                "2 bad input, 1 the file could not be written.")
    p.add_argument("run", metavar="RUN_DIR", help="run folder (ddrun/1: meta.json, "
                   "telemetry.csv, [groundtruth.csv])")
    p.add_argument("--report", metavar="OUT_DIR", help="the analyzer's output folder of an "
                   "analysis that included RUN_DIR (reads report.json): adds its findings")
    p.add_argument("--out", required=True, metavar="FILE.mcap", help="MCAP file to write "
                   "(replaced if it exists)")


def main(args: argparse.Namespace) -> int:
    out_dir = os.path.dirname(os.path.abspath(args.out))
    if os.path.isdir(args.out) or not os.path.isdir(out_dir):
        log.error("--out %s: not a file in an existing folder", runfmt.display(args.out))
        return 2
    def action() -> str:
        counts = export(args.run, args.out, args.report)
        return (f"{runfmt.display(args.out)}: "
                + ", ".join(f"{t} {n}" for t, n in counts.items()) + " messages")

    return _cli.run(action, (ExportError, runfmt.RunFormatError), args.out)
