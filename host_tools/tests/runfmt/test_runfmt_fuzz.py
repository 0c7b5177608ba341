"""Fuzz test of the run-format reader (hypothesis): over raw bytes of the three files and over
CSV/JSON structure built from a valid run, ``runfmt.load_run`` either returns a run or raises
``RunFormatError`` (which the tools turn into exit 2 with file, row and column); never any
other exception.  The same for the timing tool's ddtiming/1 reader.

Bounded in time: FUZZ_EXAMPLES (default 100) examples per strategy, about 10 s in all on the
development machine, derandomized (the same examples every run) unless FUZZ_RANDOM is set;
``FUZZ_EXAMPLES=10000 FUZZ_RANDOM=1`` for a long exploring run."""
from __future__ import annotations

import json
import math
import os
import tempfile
import warnings

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from host_tools import runfmt, timing
from test_runfmt import _columns

N = int(os.environ.get("FUZZ_EXAMPLES", "100"))
SETTINGS = settings(max_examples=N, deadline=None,
                    derandomize=not os.environ.get("FUZZ_RANDOM"),
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

_BASE = tempfile.mkdtemp(prefix="runfmt-fuzz-")
_VALID = os.path.join(_BASE, "valid")
_c = _columns(n=12, turn=2.0)
runfmt.write_run(_VALID, {"experiment": "fuzz"}, _c,
                 {"t_s": _c["t_s"] + 0.001, "x_m": _c["x_odo_m"], "y_m": _c["y_odo_m"],
                  "phi_rad": _c["phi_odo_rad"]})
VALID = {f: open(os.path.join(_VALID, f), "rb").read()
         for f in ("meta.json", "telemetry.csv", "groundtruth.csv")}


def _load(files: dict[str, bytes | None]) -> None:
    """Write the files into a fresh folder and read it every way the tools do."""
    with tempfile.TemporaryDirectory(dir=_BASE) as d:
        for name, data in files.items():
            if data is not None:
                with open(os.path.join(d, name), "wb") as fh:
                    fh.write(data)
        for kw in ({}, {"check_units": False}, {"min_rows": runfmt.ANALYZER_MIN_ROWS}):
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)  # numpy overflow is fine
                    run = runfmt.load_run(d, **kw)
            except runfmt.RunFormatError as exc:
                assert str(exc) and exc.file is not None
                continue
            for c in runfmt.TELEMETRY_COLUMNS:
                assert np.all(np.isfinite(run.telemetry[c]))
            assert np.all(np.diff(run.t_s) > 0)


FILES = st.sampled_from(["meta.json", "telemetry.csv", "groundtruth.csv"])


@SETTINGS
@given(name=FILES, data=st.binary(max_size=600))
def test_fuzz_random_bytes_in_one_file(name, data):
    _load(dict(VALID, **{name: data}))


@SETTINGS
@given(name=FILES, pos=st.integers(0, 10_000), chunk=st.binary(min_size=1, max_size=8),
       mode=st.sampled_from(["replace", "insert", "truncate"]))
def test_fuzz_byte_mutations_of_a_valid_run(name, pos, chunk, mode):
    b = VALID[name]
    pos %= len(b)
    if mode == "replace":
        b = b[:pos] + chunk + b[pos + len(chunk):]
    elif mode == "insert":
        b = b[:pos] + chunk + b[pos:]
    else:
        b = b[:pos]
    _load(dict(VALID, **{name: b}))


CELLS = st.one_of(
    st.sampled_from(["", "0", "-0", "1_0", "nan", "NaN", "inf", "-Infinity", "1e999", "-1e-999",
                     "1e308", "0x10", " 1", "1 ", "+.5", ".", "-", "e5", "1e", "١٢", "１",
                     '"', '"1"', "'1'", "\r", "\n", ",", "\x00", "\ufeff1", "9" * 400]),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-10**30, 10**30).map(str),
    st.text(max_size=12))


@SETTINGS
@given(name=st.sampled_from(["telemetry.csv", "groundtruth.csv"]), data=st.data())
def test_fuzz_csv_structure(name, data):
    rows = [r.split(",") for r in VALID[name].decode().splitlines()]
    for _ in range(data.draw(st.integers(1, 6))):
        op = data.draw(st.sampled_from(["cell", "header", "drop_col", "dup_col", "drop_row",
                                        "dup_row", "extra_field", "short_row", "swap_rows"]))
        i = data.draw(st.integers(1, len(rows) - 1)) if len(rows) > 1 else 0
        j = data.draw(st.integers(0, max(0, len(rows[0]) - 1)))
        if op == "cell" and len(rows) > 1 and j < len(rows[i]):
            rows[i][j] = data.draw(CELLS)
        elif op == "header" and j < len(rows[0]):
            rows[0][j] = data.draw(st.one_of(CELLS, st.sampled_from(rows[0])))
        elif op == "drop_col":
            rows = [r[:j] + r[j + 1:] for r in rows]
        elif op == "dup_col":
            rows = [r + r[j:j + 1] for r in rows]
        elif op == "drop_row" and len(rows) > 1:
            del rows[i]
        elif op == "dup_row" and len(rows) > 1:
            rows.insert(i, list(rows[i]))
        elif op == "extra_field" and len(rows) > 1:
            rows[i].append(data.draw(CELLS))
        elif op == "short_row" and len(rows) > 1 and rows[i]:
            rows[i].pop()
        elif op == "swap_rows" and len(rows) > 2:
            k = data.draw(st.integers(1, len(rows) - 1))
            rows[i], rows[k] = rows[k], rows[i]
    text = "\n".join(",".join(r) for r in rows) + data.draw(st.sampled_from(["", "\n", "\n\n"]))
    _load(dict(VALID, **{name: text.encode("utf-8", "surrogatepass")}))


JSON_LEAF = st.one_of(st.none(), st.booleans(), st.integers(-10**20, 10**20),
                      st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=8))
JSON = st.recursive(JSON_LEAF, lambda kids: st.one_of(
    st.lists(kids, max_size=4), st.dictionaries(st.text(max_size=6), kids, max_size=4)),
    max_leaves=12)
META_KEYS = st.sampled_from(["format", "experiment", "source", "torque_clamp", "robot", "motor",
                             "encoder_ppr", "periods_s", "start_pose", "reference", "commands"])
SUB_KEYS = st.sampled_from(list(runfmt.DEFAULT_META["robot"]) + list(runfmt.DEFAULT_META["motor"])
                           + ["inner", "outer", "telemetry", "kind", "accel", "cruise", "radius",
                              "t0_s", "unknown"])


@SETTINGS
@given(data=st.data())
def test_fuzz_meta_json_structure(data):
    meta = json.loads(VALID["meta.json"])
    for _ in range(data.draw(st.integers(1, 5))):
        key = data.draw(META_KEYS)
        if data.draw(st.booleans()) and isinstance(meta.get(key), dict):
            meta[key][data.draw(SUB_KEYS)] = data.draw(JSON)
        elif key in ("robot", "motor", "periods_s", "reference") and data.draw(st.booleans()):
            meta[key] = data.draw(st.dictionaries(SUB_KEYS, JSON, max_size=5))
        else:
            meta[key] = data.draw(JSON)
    text = json.dumps(meta)  # NaN and Infinity as Python writes them: JSON that json accepts
    _load(dict(VALID, **{"meta.json": text.encode()}))


@SETTINGS
@given(doc=st.one_of(JSON, st.dictionaries(
    st.sampled_from(["format", "isr", "tasks", "other_isr", "f_cpu_hz", "source"]),
    JSON, max_size=5).map(lambda d: dict(d, format="ddtiming/1"))))
def test_fuzz_timing_sim_file(doc):
    with tempfile.TemporaryDirectory(dir=_BASE) as d:
        p = os.path.join(d, "sim.json")
        with open(p, "w") as fh:
            json.dump(doc, fh)
        try:
            sim = timing.load_sim(p)
        except timing.TimingInputError as exc:
            assert str(exc)
            return
        for isr in (sim.get("isr") or {}).values():
            assert math.isfinite(isr["cycles_per_event"])
