"""End-to-end tests of the analyzer on synthetic runs made with the nominal plant.

These use the same model for data and fit, so they check the machinery (replay, location,
fitting, selection, honesty paths, outputs, CLI), not the analyzer's power on real physics;
that is the job of the concealed-effect suite (host_tools.suite) with the independent truth
simulator."""
from __future__ import annotations

import json
import os

import pytest

from _native_skip import needs_native

pytestmark = needs_native()

from host_tools import _native  # noqa: E402

from host_tools.__main__ import main as cli  # noqa: E402

SUBSET = "motor_back_emf,wheel_radius,axle_coulomb,actuation_delay"


def _case(tmp_path, name, effects, profiles=("ramp", "turn"), seed=0):
    from host_tools.analyzer import synth
    return synth.make_case(tmp_path / name, effects, profiles=profiles, seed=seed)


def _analyze(paths, out, effects=SUBSET, extra=()):
    rc = cli(["analyze", *map(str, paths), "--out", str(out), "--jobs", "1",
              "--effects", effects, *extra])
    rep = json.load(open(out / "report.json")) if (out / "report.json").exists() else None
    return rc, rep


def test_null_gives_no_mismatch(tmp_path):
    paths = _case(tmp_path, "null", None, seed=3)
    rc, rep = _analyze(paths, tmp_path / "out")
    assert rc == 0
    assert rep["verdict"] == "no_mismatch"
    assert rep["selected"] == [] and rep["mismatch"] == []
    # nothing to explain, so nothing is fitted
    assert rep["candidates"] == [] and any("no candidate" in n for n in rep["notes"])


def test_back_emf_is_found_located_and_fitted(tmp_path):
    paths = _case(tmp_path, "bemf", {"motor_back_emf": {"ke_ratio": 1.3}}, seed=4)
    out = tmp_path / "out"
    rc, rep = _analyze(paths, out, effects=SUBSET + ",axle_viscous")
    assert rc == 0
    assert rep["format"] == "mismatch-report/1"
    assert rep["verdict"] == "explained"
    named = {s["effect"] for s in rep["selected"]} | {q for s in rep["selected"]
                                                       for q in s["equivalent"]}
    assert "motor_back_emf" in named
    # back-EMF and viscous axle friction are the same torque law in the duty-driven plant:
    # the report must say they cannot be told apart, and how to separate them
    sel = rep["selected"][0]
    assert {sel["effect"], *sel["equivalent"]} >= {"motor_back_emf", "axle_viscous"}
    assert sel["separating_measurement"]
    bemf = next(c for c in rep["candidates"] if c["effect"] == "motor_back_emf")
    assert bemf["params"]["ke_ratio"] == pytest.approx(1.3, rel=0.03)
    assert bemf["delta_bic"] < -10 and bemf["heldout_rmse_after"] < bemf["heldout_rmse_before"]
    # located: wheel-speed windows in the duty replay, regime named
    win = [m for m in rep["mismatch"] if m["channel"].startswith("omega") and
           m["replay"] == "duty"]
    assert win and all(m["rms"] > m["noise_floor"] for m in win)
    assert all(m["regime"] for m in win)
    f = rep["fit"]
    for ch in ("omega_r", "omega_l"):
        assert f["rmse_after"][ch] < 0.5 * f["rmse_before"][ch]
        assert f["heldout_rmse_after"][ch] <= f["heldout_rmse_before"][ch]
    # outputs beside report.json
    assert (out / "report.md").read_text().startswith("# Mismatch report")
    pngs = [p for p in os.listdir(out) if p.endswith(".png")]
    # one plot per mismatched channel: both wheels, not just a default
    assert any("omega_r" in p for p in pngs) and any("omega_l" in p for p in pngs)
    model = json.load(open(out / "model.json"))
    assert model["format"] == "ddmodel/1"
    assert model["effects"][sel["effect"]]
    assert 0 < model["tau_max_nm"]["min"] < 1


def test_effect_outside_the_fitted_set_is_unexplained_with_a_hint(tmp_path):
    # gain asymmetry is not among the candidates here: nothing may claim it
    paths = _case(tmp_path, "asym", {"motor_gain_asymmetry": {"ratio": 0.8}}, seed=5)
    rc, rep = _analyze(paths, tmp_path / "out", effects="motor_back_emf,axle_coulomb")
    assert rc == 0
    assert rep["verdict"] == "unexplained"
    assert rep["mismatch"]
    assert rep["hint"] and rep["hint"]["text"]


def test_single_run_uses_a_time_split(tmp_path):
    paths = _case(tmp_path, "one", {"wheel_radius": {"r_eff": 0.039}}, profiles=("brake",),
                  seed=6)
    rc, rep = _analyze(paths, tmp_path / "out", extra=["--no-plots"])
    assert rc == 0
    assert rep["fit"]["heldout_method"].startswith("time split")
    assert rep["verdict"] == "explained"
    assert rep["selected"][0]["effect"] == "wheel_radius"
    assert rep["selected"][0]["params"]["r_eff"] == pytest.approx(0.039, rel=0.02)


# ------------------------------------------------------------------------ bad input


def _one_good_run(tmp_path):
    return _case(tmp_path, "good", None, profiles=("ramp",), seed=7)[0]


def test_bad_input_exit_2_with_where(tmp_path, capsys):
    run = _one_good_run(tmp_path)
    rc, _ = _analyze([tmp_path / "missing"], tmp_path / "o1")
    assert rc == 2 and "not a directory" in capsys.readouterr().err
    # NaN in a telemetry cell
    lines = open(os.path.join(run, "telemetry.csv")).read().splitlines()
    cells = lines[7].split(",")
    cells[3] = "nan"
    lines[7] = ",".join(cells)
    open(os.path.join(run, "telemetry.csv"), "w").write("\n".join(lines) + "\n")
    rc, _ = _analyze([run], tmp_path / "o2")
    err = capsys.readouterr().err
    assert rc == 2
    assert "telemetry.csv" in err and "row 7 (line 8)" in err and "omega_r" in err
    assert not (tmp_path / "o2" / "report.json").exists()


def test_disagreeing_parameters_exit_2(tmp_path, capsys):
    from host_tools.analyzer import synth
    a = synth.make_run(tmp_path / "a", "ramp", None, seed=1)
    b = synth.make_run(tmp_path / "b", "ramp", None, seed=2, meta={"robot": {"r": 0.04}})
    rc, _ = _analyze([a, b], tmp_path / "o")
    err = capsys.readouterr().err
    assert rc == 2 and "disagree on 'robot.r'" in err


def test_unknown_format_and_unknown_effect_exit_2(tmp_path, capsys):
    run = _one_good_run(tmp_path)
    rc, _ = _analyze([run], tmp_path / "o", effects="no_such_effect")
    assert rc == 2 and "unknown effect" in capsys.readouterr().err
    meta = json.load(open(os.path.join(run, "meta.json")))
    meta["format"] = "ddrun/9"
    json.dump(meta, open(os.path.join(run, "meta.json"), "w"))
    rc, _ = _analyze([run], tmp_path / "o")
    assert rc == 2 and "unknown format version 'ddrun/9'" in capsys.readouterr().err


def test_help_documents_the_command(capsys):
    with pytest.raises(SystemExit) as e:
        cli(["analyze", "--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert "--out" in out and "exit status" in out and "report.json" in out


def test_every_vocabulary_effect_has_a_fitting_spec_with_neutral_inside_bounds():
    from host_tools.analyzer import effects as fx
    from host_tools.runfmt import validate_meta
    meta = validate_meta({})
    vocab = _native.effect_vocabulary()
    assert set(vocab) <= set(fx.SPECS), "effects unknown to analyzer/effects.py"
    for name, params in vocab.items():
        spec = fx.spec_for(name, params)
        # each vocabulary parameter is set by exactly one fitted coordinate
        assert sorted(p.sets[0] if p.sets else p.name for p in spec.params) == sorted(params)
        for p in spec.params:
            assert p.lo(meta) <= p.neutral(meta) <= p.hi(meta), (name, p.name)
            assert p.tol is None or p.tol(meta) >= 0
