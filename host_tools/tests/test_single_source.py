"""Facts written once: the reference kinds (protocol.json's ``profile`` enum), the scheduler
tick (protocol.json timing.sched_tick_us, board.h's SCHED_TICK_HZ), the firmware's periods in
the truth simulator's recorder, and the model file's format name; every user reads the one
source."""
import os
import re

from host_tools import control, model, protocol, truth
from host_tools.analyzer.prepare import timing
from host_tools.analyzer.replay import closedloop
from host_tools.analyzer.report import model as report_model
from host_tools.suite import conceal

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _source(rel: str) -> str:
    with open(os.path.join(ROOT, rel)) as fh:
        return fh.read()


def test_reference_kinds_are_the_protocols_profiles():
    profile = protocol.definition().enums["profile"]
    assert control.REF_KINDS == {("line" if k == "straight" else k): v for k, v in profile.items()}
    assert control.REF_KINDS["line"] == profile["straight"]
    # the closed-loop replay takes the profiles and the firmware's drive mode
    assert closedloop.REF_KINDS == (*control.REF_KINDS, "drive")
    assert conceal.REF_KINDS is control.REF_KINDS
    assert truth._REF_KINDS is control.REF_KINDS
    for rel in ("host_tools/analyzer/replay/closedloop.py", "host_tools/suite/conceal.py"):
        assert '"line", "arc", "figure_eight"' not in _source(rel), rel


def test_scheduler_tick_is_protocol_jsons_and_the_boards():
    tick_us = protocol.definition().timing["sched_tick_us"]
    with open(os.path.join(ROOT, "include", "board.h")) as fh:
        hz = int(re.search(r"#define SCHED_TICK_HZ (\d+)UL", fh.read()).group(1))
    assert tick_us * hz == 1_000_000
    assert timing.RAMP_STEP_S == control.SCHED_TICK_S == tick_us / 1e6
    app = _source("src/app.cpp")
    assert "/ 1000u" not in app and "proto::kSchedTickUs" in app


def test_recorder_periods_are_the_task_tables():
    tasks = {t["name"]: t["period_us"] / 1e6 for t in protocol.definition().timing["tasks"]}
    assert truth.RECORDER_DEFAULTS["inner_s"] == tasks["inner"]
    assert truth.RECORDER_DEFAULTS["tel_s"] == tasks["telemetry"]
    assert not re.search(r"\b0\.0(25|20?)\b", _source("host_tools/truth/recorder.py"))


def test_model_format_is_host_tools_models():
    assert report_model.MODEL_FORMAT == model.FORMAT
    assert '"ddmodel/1"' not in _source("host_tools/analyzer/report/model.py")
