"""params/params.json is the one parameter table: the generated files match it, every consumer
takes its defaults and ranges from it, and no copy of its values is written anywhere else."""
from __future__ import annotations

import copy
import json
import math
import re
import runpy
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from host_tools import params

ROOT = Path(__file__).resolve().parents[2]


def _generator() -> SimpleNamespace:
    """params/generate.py's functions and paths (it is a script, not a package module)."""
    return SimpleNamespace(**runpy.run_path(str(ROOT / "params" / "generate.py"),
                                            run_name="params_generate"))


def _spec() -> dict:
    return json.loads(params.TABLE_PATH.read_text(encoding="utf-8"))


# ------------------------------------------------------------------ generated files


def test_generated_files_are_current():
    """The committed header and table are what the generator makes of params.json now, and
    its --check mode (the same comparison, for a shell) agrees."""
    gen = _generator()
    t = params.load()
    for path, render in gen.OUTPUTS:
        assert path.read_text(encoding="utf-8") == render(t), (
            f"{path.relative_to(ROOT)} drifted from params/params.json; run python3 params/generate.py")
    r = subprocess.run([sys.executable, str(ROOT / "params" / "generate.py"), "--check"],
                       capture_output=True, text=True)
    assert (r.returncode, r.stderr) == (0, "")


def test_a_changed_table_changes_the_header():
    gen = _generator()
    base = gen.render_header(params.parse(_spec()))
    for mutate in (
        lambda d: d["groups"]["robot"]["params"][0].__setitem__("value", 0.3),
        lambda d: d["groups"]["robot"]["params"][11].__setitem__("max", 0.5),
        lambda d: d["groups"]["motor"]["params"].pop(),
        lambda d: d["encoder"].__setitem__("value", 2000),
    ):
        d = copy.deepcopy(_spec())
        mutate(d)
        assert gen.render_header(params.parse(d)) != base


@pytest.mark.parametrize("mutate, message", [
    (lambda d: d["groups"]["robot"]["params"][0].__setitem__("value", 200.0), "outside its range"),
    (lambda d: d["groups"]["robot"]["params"].append(d["groups"]["robot"]["params"][0]), "twice"),
    (lambda d: d["groups"]["motor"]["params"][0].pop("unit"), "'unit' missing"),
    (lambda d: d["groups"]["robot"]["params"][2].__setitem__("name", "2b"), "C identifier"),
    (lambda d: d["encoder"].__setitem__("value", 1856.5), "integers"),
    (lambda d: d["groups"]["robot"]["params"][3].__setitem__("min", float("nan")), "finite"),
    (lambda d: d["groups"]["robot"]["params"][0].pop("tol"), "'tol' missing"),
    (lambda d: d["groups"]["robot"]["params"][0].__setitem__("tol", -0.01), "tol must be"),
    (lambda d: d["groups"]["robot"]["params"][2].__setitem__("tol", 2.0), "leaves the range"),
    (lambda d: d["groups"]["motor"]["params"][1].__setitem__("tol_ref", " "), "tol_ref"),
    (lambda d: d["model"]["params"][0].__setitem__("value", 1.5), "outside its range"),
    (lambda d: d["model"].__setitem__("params", {}), "model: 'params' must be a list"),
])
def test_table_errors_are_refused(mutate, message):
    d = copy.deepcopy(_spec())
    mutate(d)
    with pytest.raises(params.TableError, match=message):
        params.parse(d)


def test_every_parameter_has_a_tolerance_and_its_source():
    """Each nominal value is known to a tolerance, with where it comes from; params.md shows it."""
    md = (ROOT / "params" / "params.md").read_text(encoding="utf-8")
    for p in params.TABLE.params + (params.TABLE.encoder,) + params.TABLE.model:
        assert p.tol >= 0 and p.tol_ref.strip(), p.name
        assert p.tol_ref in md, p.name
    # the nominal model's settings that no table gives (section "model"): with their tolerance,
    # outside meta.json and the protocol
    assert set(params.MODEL) == {"spin_share"}
    assert params.TOLERANCES[("model", "spin_share")] > 0
    assert not any(p.run_format for p in params.TABLE.model)
    assert params.TOLERANCES[("robot", "b")] == 0.0025          # 2b = 0.21 m to its last digit
    assert params.TOLERANCES[("motor", "no_load_rad_s")] == pytest.approx(0.1 * 36.65)


# ------------------------------------------------------------------ consumers agree


def test_host_defaults_and_ranges_are_the_table():
    from host_tools import protocol, runfmt

    t = params.load()
    for group in params.GROUPS:
        want = {p.name: p.value for p in t.group(group, run_format_only=True)}
        assert runfmt.DEFAULT_META[group] == want
        assert protocol.definition().robot_defaults[group] == want
        for p in t.group(group, run_format_only=True):
            assert runfmt._PARAM_RANGES[(group, p.name)] == (p.min, p.max)
    assert runfmt.DEFAULT_META["encoder_ppr"] == t.encoder.value
    assert protocol.definition().robot_defaults["encoder_ppr"] == t.encoder.value


def test_params_message_carries_the_run_format_parameters():
    """The protocol's Params message (what the firmware reports) has exactly the table's
    run-format parameters, in the table's order, in its robot and motor groups."""
    from host_tools import protocol

    fields = protocol.definition().by_name["Params"].fields
    for group in params.GROUPS:
        assert [f.name for f in fields if f.spec.get("group") == group] == \
            [p.name for p in params.TABLE.group(group, run_format_only=True)]
    assert "encoder_ppr" in [f.name for f in fields]


def test_period_defaults_are_the_protocol_task_table():
    from host_tools import control, protocol, runfmt

    tasks = {t["name"]: t["period_us"] for t in protocol.definition().timing["tasks"]}
    assert {k: round(v * 1e6) for k, v in runfmt.DEFAULT_META["periods_s"].items()} == tasks
    assert control.INNER_S * 1e6 == pytest.approx(tasks["inner"])


def test_native_plant_keys_defaults_and_ranges_are_the_table():
    """lib/slipmodel (through the generated header): the same keys in the same order, the same
    defaults, and exactly the table's range accepted (the bounds in, the next double out)."""
    from host_tools import _native

    t = params.load()
    assert _native.param_keys() == [f"{p.group}.{p.name}" for p in t.params]
    plant = _native.Plant()
    for p in t.params:
        key = f"{p.group}.{p.name}"
        assert plant.get(key) == p.value, key
        for ok in (p.min, p.max):
            plant.set(key, ok)
        for bad in (math.nextafter(p.min, -math.inf), math.nextafter(p.max, math.inf)):
            with pytest.raises(ValueError, match="bad value"):
                plant.set(key, bad)
        plant.set(key, p.value)
    vocab = _native.effect_vocabulary()
    r = t.defaults("robot")
    assert vocab["friction_coefficient"] == {"mu_s": r["mu_s"], "mu_k": r["mu_k"]}
    assert vocab["wheel_radius"] == {"r_eff": r["r"]}
    assert vocab["track_width"] == {"b_eff": r["b"]}
    assert vocab["load_transfer"] == {"h": r["h"]}
    assert vocab["stribeck"]["mu_k0"] == r["mu_k"]


def test_controller_abi_defaults_and_ranges_are_the_table():
    from host_tools.control import Controller

    t = params.load()
    c = Controller()
    for p in t.params:
        assert c.get(p.name) == p.value, p.name
        with pytest.raises(ValueError):
            c.set(p.name, math.nextafter(p.max, math.inf))
        c.set(p.name, p.value)


def test_truth_simulator_defaults_and_ranges_are_the_table():
    """The truth simulator is a second implementation of the physics, not of the parameters:
    its robot.*, motor.* and ctl.* defaults and ranges are the table's."""
    from host_tools.truth import TruthSim

    t = params.load()
    s = TruthSim()
    for prefix in ("", "ctl."):
        for p in t.params:
            key = f"{prefix or p.group + '.'}{p.name}"
            assert s.get(key) == p.value, key
            s.set(key, p.min)
            s.set(key, p.max)
            with pytest.raises(ValueError):
                s.set(key, math.nextafter(p.max, math.inf))
            with pytest.raises(ValueError):
                s.set(key, math.nextafter(p.min, -math.inf))


def test_suite_neutral_values_are_the_table():
    from host_tools.suite import cases

    r = params.ROBOT
    assert cases.NEUTRAL["friction_coefficient"] == {"mu_s": r["mu_s"], "mu_k": r["mu_k"]}
    assert cases.NEUTRAL["wheel_radius"] == {"r_eff": r["r"]}
    assert cases.NEUTRAL["track_width"] == {"b_eff": r["b"]}
    assert cases.R == r["r"]


# ------------------------------------------------------------------ the table is the thesis's


def test_the_table_is_the_thesis():
    """The one place outside params/params.json where the values are written: typed here from
    the thesis (Table II.2; III.1 for the motor and the encoder), so that a changed table is a
    decision, not a slip.  Every other test takes them from the table."""
    thesis = {
        "robot": {"mu_s": 0.241, "mu_k": 0.239, "b": 0.105, "e": 0.095, "d": 0.055, "g": 9.81,
                  "h": 0.0216, "m_r": 1.5, "I_rz": 0.009753, "I_wz": 0.000584, "I_wy": 0.001168,
                  "r": 0.0365, "m_w": 0.064},
        "motor": {"supply_v": 12.0, "no_load_rad_s": 36.65, "stall_nm": 0.77, "stall_a": 2.0},
    }
    t = params.load()
    for group, values in thesis.items():
        assert t.defaults(group, run_format_only=False) == values, group
    assert t.encoder.value == 1856
    assert 350 * 2 * math.pi / 60 == pytest.approx(thesis["motor"]["no_load_rad_s"], abs=5e-3)


# ------------------------------------------------------------------ no copies in the tree

#: Table values distinctive enough to grep for (the round ones, 1.5, 2.0 and 12.0, are not).
_DISTINCTIVE = ("0.241", "0.239", "0.105", "0.095", "0.055", "9.81", "0.0216", "0.009753",
                "0.000584", "0.001168", "0.0365", "0.064", "36.65", "0.77", "1856")
#: Where such a number is not a copy of the table's value: (path, value) -> why.
_NOT_COPIES = {
    ("host_tools/demo/common.py", "0.095"): "the thesis's stated tau_max (II.6), compared with the model's",
    ("bench/logger/avr_codec_cycles.cpp", "36.65"): "arbitrary inputs of the codec cycle benchmark",
    ("bench/logger/avr_codec_cycles.cpp", "0.095"): "arbitrary inputs of the codec cycle benchmark",
    ("bench/logger/avr_codec_cycles.cpp", "0.77"): "arbitrary inputs of the codec cycle benchmark",
    ("host_tools/analyzer/select.py", "0.77"): "analyzer score figures in a comment",
    ("host_tools/suite/sets.json", "0.055"):
        "a load_transfer effect size (h) and a recorder's inner loop (inner_s = 55 ms), not d",
    ("host_tools/suite/sets.json", "0.095"): "a load_transfer effect size (h = 95 mm), not tau_max",
    ("host_tools/suite/sets.json", "0.105"): "a recorder's telemetry period (tel_s = 105 ms), not b",
    ("host_tools/suite/sets.json", "0.064"): "a recorder's telemetry period (tel_s = 64 ms), not m_w",
    ("host_tools/suite/sets.json", "0.0216"):
        "a floor_slope effect size (rad = 0.0216, heldback33's, drawn), not h",
    ("host_tools/suite/sets.json", "0.0365"):
        "an eccentric_wheel effect size (eps = 0.0365, heldback35's, drawn), not r",
}
#: The same for the tests, which take the table's values from host_tools.params (Python) and
#: slip::table / SLIP_*_PARAMS / slip::table_ii2() (C++): (path, value) -> (how many, why).
#: The count is exact, so a new copy in a listed file fails as well as a stale entry.
_TEST_NOT_COPIES = {
    ("host_tools/tests/demo/test_demo.py", "0.095"): (1, "the thesis's printed tau_max in the demo's table"),
    ("test/native/test_slipmodel_traction/test_traction.cpp", "0.095"):
        (4, "the thesis's printed tau_max, which no variant of the model reproduces"),
    ("test/embedded/test_protocol/test_protocol.cpp", "36.65"):
        (2, "inputs of the golden Telemetry frame (raw values in test_protocol_generated.py)"),
    ("test/embedded/test_protocol/test_protocol.cpp", "0.095"):
        (1, "inputs of the golden Telemetry frame (raw values in test_protocol_generated.py)"),
    ("test/embedded/test_protocol/test_protocol.cpp", "0.77"):
        (1, "inputs of the golden Telemetry frame (raw values in test_protocol_generated.py)"),
    ("test/native/test_protocol/test_protocol.cpp", "36.65"):
        (2, "codec round-trip inputs, the embedded golden frame's sample"),
    ("test/native/test_protocol/test_protocol.cpp", "0.095"):
        (1, "codec round-trip inputs, the embedded golden frame's sample"),
    ("test/native/test_protocol/test_protocol.cpp", "0.77"):
        (2, "codec round-trip inputs, the embedded golden frame's sample"),
}
#: The table and the files generated from it.
_TABLE_FILES = {"params/params.json", "params/params.md",
                "lib/slipmodel/src/slipmodel/params_table.h"}
#: This file: the grep's own list and the one check of the table against the thesis.
_THIS_FILE = "host_tools/tests/test_params_generated.py"
_SOURCE = re.compile(r"\.(py|c|cpp|h|S|json|ini|sh|toml)$")
_TEST_DIRS = ("test/", "host_tools/tests/")


def _literal(value: str) -> re.Pattern:
    # the number itself, not a longer one that contains it (0.0365 in 0.03650 or 10.0365)
    return re.compile(r"(?<![\w.])" + re.escape(value) + r"(?![\w.]*\d)")


def _copies(tests: bool) -> dict[tuple[str, str], list[int]]:
    """{(path, value): [line, ...]} of the distinctive values in the tracked source files
    outside the table, either in the tests or outside them."""
    files = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True,
                           check=True).stdout.split()
    found: dict[tuple[str, str], list[int]] = {}
    for rel in files:
        if (not _SOURCE.search(rel) or rel in _TABLE_FILES or rel == _THIS_FILE
                or rel.startswith(_TEST_DIRS) != tests or not (ROOT / rel).is_file()):
            continue
        text = (ROOT / rel).read_text(encoding="utf-8", errors="replace")
        for value in _DISTINCTIVE:
            for m in _literal(value).finditer(text):
                found.setdefault((rel, value), []).append(text.count("\n", 0, m.start()) + 1)
    return found


def test_no_copy_of_the_table_in_the_source_tree():
    found = [f"{rel}:{line}: {value}" for (rel, value), lines in _copies(tests=False).items()
             if (rel, value) not in _NOT_COPIES for line in lines]
    assert not found, ("Table values written outside params/params.json (derive them from "
                       "the table, or list a true non-copy in _NOT_COPIES):\n" + "\n".join(found))


def test_no_copy_of_the_table_in_the_tests():
    found = _copies(tests=True)
    bad = [f"{rel}:{line}: {value}" for (rel, value), lines in found.items()
           if (rel, value) not in _TEST_NOT_COPIES for line in lines]
    assert not bad, ("Table values written in tests (take them from host_tools.params or "
                     "slip::table, or list a true non-copy in _TEST_NOT_COPIES):\n" + "\n".join(bad))
    counts = {k: (len(found.get(k, [])), n) for k, (n, _) in _TEST_NOT_COPIES.items()}
    assert all(have == want for have, want in counts.values()), (
        "_TEST_NOT_COPIES counts differ from the tests (found, listed): "
        + str({k: v for k, v in counts.items() if v[0] != v[1]}))


def test_the_copy_finder_finds_a_copy():
    pat = _literal("0.0365")
    assert pat.search("r = 0.0365  # m") and pat.search("{0.0365, 0.0}")
    assert not pat.search("r = 0.03650") and not pat.search("10.0365") and not pat.search("0.03651")
