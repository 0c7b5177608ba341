"""Which fitted parameters the data identify, on truth-simulator runs (docs/analyzer.md,
"Identifiability")."""
from __future__ import annotations

import json

import pytest

from _native_skip import needs_native

pytestmark = needs_native(truth=True)

from host_tools import truth  # noqa: E402
from host_tools.__main__ import main as cli  # noqa: E402
from _truth_loads import slip_load_ratio  # noqa: E402
from host_tools import params  # noqa: E402

SLIPPING = {"friction_coefficient": {"mu_s": 0.17, "mu_k": 0.16}}


def test_mu_s_unidentified_when_the_wheels_slip_all_run(tmp_path):
    """Without the torque clamp, hard starts on a slippery floor: the wheels slip from the
    first moments to the end, which pins mu_k and says nothing about mu_s.  In the fit's
    coordinates (mu_s, mu_k/mu_s) both move mu_k, so mu_s had looked identified (std 0.0012)
    and was kept at its nominal value without a word; it is now reported as unidentified,
    with mu_k fitted and the verdict explained.  The cost is flat in mu_s from mu_k up to the
    lowest commanded traction, beyond mu_s's possible range [mu_k, 2 mu_k] here: the report's
    profile set says so (`unbounded`, both edges null)."""
    runs = [truth.simulate_run(tmp_path / f"run{i}", {"kind": "line", "accel": a, "cruise": v},
                               SLIPPING, clamp=False, duration_s=1.5, seed=40 + i,
                               hidden_dir=tmp_path / "hidden")
            for i, (a, v) in enumerate([(3.0, 1.0), (2.5, 0.9)])]
    out = tmp_path / "out"
    assert cli(["analyze", *runs, "--out", str(out), "--jobs", "1", "--no-plots",
                "--effects", "friction_coefficient"]) == 0
    rep = json.load(open(out / "report.json"))
    assert rep["verdict"] == "explained"
    sel = {s["effect"]: s for s in rep["selected"]}
    fc = sel["friction_coefficient"]
    # the truth's wheels carry more while they slip than the nominal model's law gives for the
    # same motion (their whole spin-up reacts, k = 1 against the nominal k^ h_s): the fitted
    # mu_k is the true one times that ratio of the loads, to 2 %
    want = SLIPPING["friction_coefficient"]["mu_k"] * slip_load_ratio(tmp_path / "hidden")
    assert abs(fc["params"]["mu_k"] - want) < want * 0.02
    assert "mu_s" in fc["unidentified"]
    assert fc["params"]["mu_s"] >= fc["params"]["mu_k"]
    iv = fc["interval"]["mu_s"]
    assert iv["kind"] == "unbounded" and iv["lo"] is None and iv["hi"] is None
    # the set was scanned along the line of the fit's mu_k; the refit with mu_s pinned at the
    # nominal model's point on that line (mu_k times the nominal mu_s/mu_k, just above mu_k)
    # refits mu_k, which the re-grips of wheels whose mu_s is that close to mu_k move by
    # under 1 %
    assert abs(iv["possible"][0] - fc["params"]["mu_k"]) < 1e-2 * fc["params"]["mu_k"]
    ratio = params.ROBOT["mu_s"] / params.ROBOT["mu_k"]
    assert fc["params"]["mu_s"] == pytest.approx(iv["possible"][0] * ratio, rel=1e-4)
    assert iv["flat"] == iv["possible"]
    assert "mu_s not bounded within" in open(out / "report.md").read()
