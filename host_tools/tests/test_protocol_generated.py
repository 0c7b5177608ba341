"""The committed generated files must match protocol/protocol.json (one source of truth)."""
from __future__ import annotations

import copy
import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _generator():
    spec = importlib.util.spec_from_file_location("protocol_generate", ROOT / "protocol" / "generate.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_committed_header_matches_definition():
    gen = _generator()
    defn = gen.load()
    assert gen.HEADER.read_text(encoding="utf-8") == gen.render_header(defn), (
        "lib/protocol/src/protocol/messages.h drifted from protocol/protocol.json; "
        "run python3 protocol/generate.py")
    assert gen.TABLES.read_text(encoding="utf-8") == gen.render_tables(defn)


def test_check_mode_exit_code():
    r = subprocess.run([sys.executable, str(ROOT / "protocol" / "generate.py"), "--check"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr


def test_drift_is_detected():
    """A change of the definition changes the rendered header, so the check above can fail."""
    gen = _generator()
    defn = gen.load()
    base = gen.render_header(defn)
    for mutate in (
        lambda d: d["messages"][0]["fields"][3].__setitem__("scale", 0.02),
        lambda d: d["messages"][3]["fields"][1].__setitem__("max", 150.0),
        lambda d: d["messages"][0]["fields"].pop(),
        lambda d: d["timing"]["tasks"][0].__setitem__("budget_cycles", 1),
        lambda d: d.__setitem__("version", d["version"] + 1),
    ):
        d = copy.deepcopy(defn)
        mutate(d)
        assert gen.render_header(d) != base


def test_definition_errors_are_refused():
    gen = _generator()
    d = copy.deepcopy(gen.load())
    d["messages"][1]["type"] = d["messages"][0]["type"]
    with pytest.raises(gen.DefinitionError, match="reused"):
        gen.check(d)
    d = copy.deepcopy(gen.load())
    d["messages"][3]["fields"][1]["max"] = 1000.0  # 100000 raw > u16
    with pytest.raises(gen.DefinitionError, match="does not fit"):
        gen.check(d)
    d = copy.deepcopy(gen.load())
    d["messages"][3]["fields"][1]["min"] = 0.015  # not a multiple of the 0.01 scale
    with pytest.raises(gen.DefinitionError, match="multiple of scale"):
        gen.check(d)


def test_python_codec_uses_the_same_layout():
    """host_tools.protocol and the generator agree on every payload size."""
    from host_tools import protocol

    gen = _generator()
    defn = gen.load()
    pd = protocol.Definition()
    for m in defn["messages"]:
        assert pd.by_name[m["name"]].size == gen.payload_size(m)
        assert pd.by_name[m["name"]].type == m["type"]


def _golden(text: str, label: str) -> bytes:
    import re

    m = re.search(r"// GOLDEN " + re.escape(label) + r"\n[^{]*\{([^}]*)\}", text)
    assert m, f"golden vector {label!r} not found"
    return bytes(int(x, 16) for x in re.findall(r"0x([0-9a-fA-F]{2})", m.group(1)))


def test_embedded_golden_vectors():
    """test/embedded/test_protocol compares the AVR's frames with golden vectors; they must be
    what the host codec produces today for the same values (else the AVR test checks a stale
    protocol)."""
    from host_tools import protocol

    d = protocol.Definition()
    text = (ROOT / "test" / "embedded" / "test_protocol" / "test_protocol.cpp").read_text()
    names = d.by_name["Telemetry"].field_names()
    v = dict.fromkeys(names, 0)
    v.update(t_us=4294967000, enc_r=-123456, enc_l=2147483647, omega_r=3665, omega_l=-1250,
             tau_cmd_r=950, tau_cmd_l=-7700, pwm_r=10000, pwm_l=-2500, x_odo=1234567, y_odo=-500000,
             phi_odo=6500000, inner_last=771, inner_max=65535, inner_overruns=3, illegal_l=7, status=3,
             failsafe=1, reset_cause=8, current_r=1023, stack_hwm=812, boot_count=513,
             v_ref=300, omega_ref=-1250, v_cmd=300, omega_cmd=-1250, ref_t0_us=123456789)
    assert _golden(text, "Telemetry seq=65535") == d.encode_raw("Telemetry", 65535, [v[n] for n in names])
    p = dict(d.robot_defaults["robot"], **d.robot_defaults["motor"])
    p.update(encoder_ppr=d.robot_defaults["encoder_ppr"], inner_period_us=25000, outer_period_us=50000, telemetry_period_us=20000,
             baud=115200, clamp_on=1, controller=d.enums["controller"]["thesis"], firmware_id=0x12345678,
             ke_ratio=1.0, drop_v=0.0)
    assert _golden(text, "Params seq=7") == d.encode_raw("Params", 7, [p[f.name] for f in d.by_name["Params"].fields])


def test_link_budget_figures_in_the_readmes_are_the_definitions():
    """The frame sizes and the telemetry load quoted in README.md and protocol/README.md are
    typed there for the reader: they must be the definition's (messages.md is generated)."""
    import re

    from host_tools import protocol

    d = protocol.Definition()
    tel = d.by_name["Telemetry"]
    wire, payload = d.wire_size("Telemetry"), tel.size
    rate = tel.spec["rate_hz"]
    per_s = wire * rate
    pct = 100.0 * per_s / (d.baud / 10)
    proto_readme = (ROOT / "protocol" / "README.md").read_text()
    rows = {m.group(1).strip(): int(m.group(2))
            for m in re.finditer(r"^\| ([^|]+?) \| (\d+) \| [^|]+ \|", proto_readme, re.M)}
    assert rows["Telemetry (%d B payload)" % payload] == wire
    assert rows["Params"] == d.wire_size("Params")
    assert rows["Ack"] == d.wire_size("Ack")
    assert rows["host -> robot Heartbeat"] == d.wire_size("Heartbeat")
    assert f"| {wire} | {rate} Hz | {per_s:,}".replace(",", " ") in proto_readme
    top = (ROOT / "README.md").read_text()
    assert f"A telemetry frame is {wire} bytes on the wire ({payload} payload bytes" in top
    assert f"{wire} B frames at {rate} Hz = {per_s:,} B/s, {pct:.0f} % of" in top


def test_current_scale_is_the_current_sense():
    """The telemetry's ampere scale derives from current_sense (one home for the V/A);
    a sense gain that no longer matches the scale is refused, and the header carries it."""
    gen = _generator()
    defn = gen.load()
    vpa = gen.c_float(defn["current_sense"]["volts_per_amp"])
    assert f"kCurrentSenseVoltsPerAmp = {vpa};" in gen.render_header(defn)
    bad = copy.deepcopy(defn)
    bad["current_sense"]["volts_per_amp"] *= 1.01
    with pytest.raises(gen.DefinitionError, match="current_sense"):
        gen.check(bad)
