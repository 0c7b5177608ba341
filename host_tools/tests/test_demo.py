"""The demo's part 1 (II.6 on the nominal model): facts that must hold, not figures copied in."""
import json
import os

import pytest

from host_tools import demo


@pytest.fixture(scope="module")
def thesis(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    res = demo.thesis_reproduction(str(out / "thesis"), log=lambda *a: None)
    return out / "thesis", res


def test_outputs_written(thesis):
    d, _ = thesis
    for f in ("ii61_torque_steps.png", "ii62_profiles.png", "ii63_clamp.png", "README.md",
              "results.json"):
        assert (d / f).stat().st_size > 1000, f
    assert json.loads((d / "results.json").read_text())["tau_max_nm"] > 0
    table = (d / "README.md").read_text()
    assert "| τmax (II.51) | 0.095 N m | 0.0924 N m |" in table


def test_ii61_slip_only_above_tau_max(thesis):
    _, res = thesis
    by = {r["tau_nm"]: r for r in res["ii61"]}
    assert not by[0.09]["slip"] and abs(by[0.09]["x_slip_m"] - by[0.09]["x_rolling_m"]) < 1e-6
    assert by[0.1]["slip"] and by[0.1]["x_slip_m"] < by[0.1]["x_rolling_m"] - 0.1
    assert by[0.3]["slip"] and by[0.3]["x_slip_m"] < 0.5 * by[0.3]["x_rolling_m"]


def test_ii63_clamp_removes_slip_and_drift(thesis):
    _, res = thesis
    off, on = res["ii63"]["off"], res["ii63"]["on"]
    assert off["slip"] and not on["slip"]
    assert off["odo_drift_m"] > 0.1 and on["odo_drift_m"] < 0.005
    assert on["max_tau_cmd_nm"] <= res["tau_max_nm"] + 1e-4 < off["max_tau_cmd_nm"]


def test_ii63_ideal_torque_source(thesis):
    """As the thesis simulated (torques applied directly): the clamped robot does not slip,
    peaks no higher than the slipping one (mu_k ~ mu_s: slip costs almost no acceleration),
    recovers the reference, and its error over the run is much smaller."""
    _, res = thesis
    off, on = res["ii63"]["off_torque_source"], res["ii63"]["on_torque_source"]
    assert off["slip"] and not on["slip"]
    assert on["max_err_m"] <= off["max_err_m"] + 0.01
    assert on["final_err_m"] < 0.01 < 0.1 < off["final_err_m"]
    assert on["rms_err_m"] < 0.6 * off["rms_err_m"]


def test_ii62_no_slip_limit_follows_from_table_ii2(thesis):
    """The straight-line no-slip limit tau_max / (I_wy + m_t r^2/2) equals 2 mu_s N / (m_t r),
    and the 44 rad/s^2 profile needs more torque than tau_max; the closed loop slips there."""
    _, res = thesis
    mu_s, r, m_t = 0.241, 0.0365, 1.5 + 2 * 0.064
    n_wheel = 0.5 * m_t * 9.81 * 0.095 / (0.095 + 0.055)  # caster takes d/(d+e) of the weight
    assert abs(res["alpha_no_slip_rad_s2"] - 2 * mu_s * n_wheel / (m_t * r)) < 0.05
    by = {row["alpha_rad_s2"]: row for row in res["ii62"]}
    assert by[44.0]["tau_needed_nm"] > res["tau_max_nm"]
    assert all(row["slip"] for row in res["ii62"])


def test_analyzer_demo_end_to_end(tmp_path):
    """Part 2: the dataset is made, the analyzer runs on it and the report shows the fit
    improve (about 15-30 s)."""
    r = demo.analyzer_demo(str(tmp_path), log=lambda *a: None)
    assert r["rc"] == 0
    rep = r["report"]
    assert (tmp_path / "report" / "report.json").exists()
    assert (tmp_path / "fit_improvement.png").stat().st_size > 1000
    labels = tmp_path / "dataset" / "labels"
    runs = tmp_path / "dataset" / "runs"
    assert labels.is_dir() and not any("labels" in str(p) for p in runs.rglob("*"))
    assert rep["verdict"] == "explained" and r["score"]["named_all"]
    fit = rep["fit"]
    assert fit["heldout_rmse_after"]["omega_r"] < 0.5 * fit["heldout_rmse_before"]["omega_r"]
