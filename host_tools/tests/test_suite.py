"""The concealed-effect suite: coverage of the case list, hidden labels, deterministic
generation, the scorer, and the fast subset of the benchmark with issue 9's thresholds."""
import filecmp
import os

import pytest

from host_tools import _native
from host_tools.suite import bench, cases, generate


def test_case_list_covers_issue_9():
    cs = cases.all_cases()
    assert len(cs) >= 40
    names = {c.name for c in cs}
    assert len(names) == len(cs)
    for eff in _native.effect_vocabulary():
        assert f"{eff}_strong" in names and f"{eff}_weak" in names, eff
    assert sum(c.expect == "no_mismatch" for c in cs) >= 3
    assert sum(len(c.true_effects) >= 2 for c in cs) >= 3
    oov = {e for c in cs for e in c.effects if e in cases.OUT_OF_VOCABULARY}
    assert len(oov) >= 2
    kinds = {k for c in cs for k in c.concealment}
    assert {"compensation", "regime", "hidden_channel", "confounded"} <= kinds
    assert all(len(c.experiments) >= 3 for c in cs)


def test_generation_deterministic_and_labels_hidden(tmp_path):
    case = cases.get(["motor_gain_asymmetry_weak"])[0]
    a = generate.generate_case(case, str(tmp_path / "a"))
    b = generate.generate_case(case, str(tmp_path / "b"))
    for ra, rb in zip(a, b):
        for f in ("meta.json", "telemetry.csv", "groundtruth.csv"):
            assert filecmp.cmp(os.path.join(ra, f), os.path.join(rb, f), shallow=False)
        assert sorted(os.listdir(ra)) == ["groundtruth.csv", "meta.json", "telemetry.csv"]
        text = "".join(open(os.path.join(ra, f)).read() for f in os.listdir(ra))
        assert "asymmetry" not in text and '"ratio"' not in text
    assert (tmp_path / "a" / "labels" / "motor_gain_asymmetry_weak.json").exists()


def _label(expect, effects=None):
    c = cases.Case("x", effects or {}, cases.STD, expect)
    return c.label()


def test_scorer_can_fail():
    lab = _label("explained", {"motor_back_emf": {"ke_ratio": 1.2}})
    rep = {"verdict": "explained", "selected": [{"effect": "axle_viscous", "params": {"c": 0.004},
                                                 "equivalent": ["motor_back_emf"]}],
           "candidates": [{"effect": "motor_back_emf", "params": {"ke_ratio": 1.25}}],
           "fit": {"heldout_rmse_before": {"omega_r": 2.0}, "heldout_rmse_after": {"omega_r": 2.1}}}
    r = bench.score_case(lab, 0, rep)
    assert r["ok"] and r["param"]["fitted"] == 1.25
    assert r["param"]["rel_err_deviation"] == pytest.approx(0.25)
    assert r["heldout_worse_channels"] == ["omega_r"]
    # channel by channel without tolerance: equal is not worse, any increase is
    rep["fit"] = {"heldout_rmse_before": {"omega_r": 2.0, "x_m": 0.001},
                  "heldout_rmse_after": {"omega_r": 2.0, "x_m": 0.0010001}}
    assert bench.score_case(lab, 0, rep)["heldout_worse_channels"] == ["x_m"]
    rep["fit"]["heldout_rmse_after"]["x_m"] = 0.001
    assert bench.score_case(lab, 0, rep)["heldout_worse_channels"] == []
    rep["selected"][0]["equivalent"] = []
    assert not bench.score_case(lab, 0, rep)["ok"]
    assert not bench.score_case(_label("no_mismatch"), 0, rep)["ok"]
    assert not bench.score_case(_label("unexplained", {"battery_sag": {"r_int": 1}}), 2, None)["ok"]


def test_fast_subset_meets_thresholds(tmp_path):
    """CI subset (a null, a compensated back-EMF case, an eccentric wheel): about 50 s."""
    results, m, text = bench.bench(str(tmp_path), cases.get(fast=True), jobs=2, out=lambda s: None)
    print(text)
    assert m["null_ok"] == 1.0
    assert m["named"] >= 0.9
    assert m["param"] >= 0.8
    assert m["oov_ok"] == 1.0
    # the held-out error never gets worse: over all channels (RMS in noise floors) and channel
    # by channel (every reported channel, no tolerance)
    assert m["heldout_worse_overall"] == 0
    assert m["heldout_worse"] == 0
