"""The cost of the analyzer's fits: the held-out folds cost about a fixed number of full fits
however many runs there are (the work per run does not grow with the number of runs), and
the replays the fits ask for again are reused without changing any result."""
from __future__ import annotations

import numpy as np

from _native_skip import needs_native

pytestmark = needs_native()

from host_tools import _native  # noqa: E402
from host_tools.analyzer import synth  # noqa: E402
from host_tools.analyzer.fit import judge as JG  # noqa: E402
from host_tools.analyzer.fit import problem as PB  # noqa: E402
from host_tools.analyzer.locate.floors import noise_floors  # noqa: E402
from host_tools.analyzer.prepare import inputs as PI  # noqa: E402
from host_tools.analyzer.replay import channels as CH  # noqa: E402
from host_tools.analyzer.replay import openloop as OL  # noqa: E402
from host_tools.runfmt import load_run  # noqa: E402

_PROFILES = ("ramp", "turn", "slow", "brake")


def _problem(tmp_path, n_runs: int, duration_s: float = 0.6) -> PB.Problem:
    preps = []
    for i in range(n_runs):
        path = synth.make_run(tmp_path / f"run-{i:02d}", _PROFILES[i % 4],
                              {"motor_back_emf": {"ke_ratio": 1.25}}, duration_s=duration_s,
                              seed=500 + i)
        preps.append(PI.prepare_timed(load_run(path)))
    duty = OL.OpenLoopReplay("duty")
    nominal = [CH.channels(p, duty.simulate_windows(p, {})) for p in preps]
    return PB.Problem(preps, noise_floors(preps, nominal), _native.effect_vocabulary())


def test_heldout_folds_leave_one_run_out_up_to_the_fold_count_then_group_runs():
    # one run: a time split
    assert JG.heldout_folds(1) == [([0], [0], "early", "late")]
    # up to HELDOUT_FOLDS runs: leave one run out, in the order of the runs
    for n in range(2, JG.HELDOUT_FOLDS + 1):
        assert JG.heldout_folds(n) == [([j for j in range(n) if j != i], [i], "all", "all")
                                       for i in range(n)]
        assert JG.heldout_method(n, 0.6) == "leave one run out"
    # more runs: HELDOUT_FOLDS folds of consecutive runs, each run held out exactly once
    for n in (JG.HELDOUT_FOLDS + 1, 32, 200):
        folds = JG.heldout_folds(n)
        assert len(folds) == JG.HELDOUT_FOLDS
        assert JG.heldout_method(n, 0.6) == f"{JG.HELDOUT_FOLDS} folds of consecutive runs, each held out once"
        held = [i for _, test, _, _ in folds for i in test]
        assert held == list(range(n))
        for train, test, _, _ in folds:
            assert sorted(train + test) == list(range(n))
            assert test == list(range(test[0], test[-1] + 1))
        # the refits see about (folds - 1) full sets of runs: linear in n
        assert sum(len(train) for train, _, _, _ in folds) == (JG.HELDOUT_FOLDS - 1) * n


def test_fit_work_per_run_does_not_grow_with_the_number_of_runs(tmp_path):
    """Runs replayed by one candidate's fit and held-out folds, per run: about the same for 9
    and 18 runs (leaving out each run in turn, it doubled)."""
    per_run = []
    for n in (9, 18):
        pb = _problem(tmp_path / f"n{n}", n)
        JG.evaluate_candidate(pb, ["motor_back_emf"])
        per_run.append(pb.n_simulated / n)
    assert per_run[1] < 1.4 * per_run[0], per_run


def test_cached_replays_give_the_same_fit_and_held_out_figures(tmp_path, monkeypatch):
    pb = _problem(tmp_path, 3)
    cached = JG.evaluate_candidate(pb, ["motor_back_emf"])
    n_cached = pb.n_simulated
    # the nominal replay is asked for again: no new simulation
    pb.residual({}, [0, 1, 2])
    assert pb.n_simulated == n_cached
    monkeypatch.setattr(PB, "CACHE_BYTES", 0)
    fresh = _problem(tmp_path / "again", 3)
    plain = JG.evaluate_candidate(fresh, ["motor_back_emf"])
    assert fresh.n_simulated > n_cached          # without the cache, replays are repeated
    assert np.array_equal(cached.fit.x, plain.fit.x)
    assert cached.fit.rss == plain.fit.rss and cached.fit.std == plain.fit.std
    assert cached.fold_values == plain.fold_values
    assert (cached.heldout_before, cached.heldout_after) == (plain.heldout_before,
                                                             plain.heldout_after)
    assert cached.heldout_channels_after == plain.heldout_channels_after
    assert cached.delta_bic == plain.delta_bic and cached.output_size == plain.output_size
    for a, b in zip(cached.heldout_pooled, plain.heldout_pooled):
        assert np.array_equal(a, b)


def test_cache_tells_effects_apart_to_the_last_bit(tmp_path):
    pb = _problem(tmp_path, 1)
    e1 = {"motor_back_emf": {"ke_ratio": 1.1}}
    e2 = {"motor_back_emf": {"ke_ratio": float(np.nextafter(1.1, 2.0))}}
    r1 = pb.residual(e1, [0])
    n = pb.n_simulated
    r2 = pb.residual(e2, [0])
    assert pb.n_simulated == n + 1
    assert np.array_equal(pb.residual(e1, [0]), r1) and pb.n_simulated == n + 1
    assert np.array_equal(pb.residual(e2, [0]), r2)
    pb.forget()                                  # after a prepared run changed
    assert np.array_equal(pb.residual(e1, [0]), r1) and pb.n_simulated == n + 2


def test_fit_channels_alone_equal_those_of_all_channels(tmp_path):
    pb = _problem(tmp_path, 2, duration_s=1.0)
    eff = {"motor_back_emf": {"ke_ratio": 1.2}}
    fit_only = pb.sim_channels(eff, [0, 1], fit_only=True)
    n = pb.n_simulated
    everything = pb.sim_channels(eff, [0, 1])      # a fit-only replay cannot serve this
    assert pb.n_simulated == n + 2
    for few, all_ in zip(fit_only, everything):
        assert set(few) < set(all_) and set(pb.fit_channels) <= set(few)
        for c in few:
            assert np.array_equal(few[c].sim, all_[c].sim) and np.array_equal(few[c].t, all_[c].t)
    # the groups of channels name every channel once
    names = [c for group, _ in CH._GROUPS for c in group]
    assert sorted(names) == sorted(CH.CHANNELS)


def test_the_fit_keeps_the_wheels_difference_where_single_wheels_are_no_evidence(tmp_path):
    """In a slip of a windowed replay each wheel on its own is no evidence (SLIP_UNC) but the
    pair's difference is, as in the detection's bias test: the fit's residual holds the
    difference (r - l)/sqrt(2) in floors there, so a motor-gain asymmetry is fitted from it
    even when nothing else is evidence (the pose channels unpinned).  Without it the residual
    is nil (1e-9 floors: an unbounded uncertainty) and the update changes no output."""
    from host_tools.analyzer.locate.episodes import SLIP_UNC, UNPINNED_UNC
    path = synth.make_run(tmp_path / "run", "turn", {"motor_gain_asymmetry": {"ratio": 1.15}},
                          duration_s=1.0, seed=71)
    prep = PI.prepare_timed(load_run(path))
    duty = OL.OpenLoopReplay("duty")
    nominal = CH.channels(prep, duty.simulate_windows(prep, {}))
    floors = noise_floors([prep], [nominal])
    unc = {}
    for c, ch in nominal.items():
        if c in PB.FIT_CHANNELS:
            level = SLIP_UNC if c.startswith(("omega", "current")) else UNPINNED_UNC
            unc[c] = (ch.t.copy(), np.full(ch.t.size, level))
    prep.replay_unc = unc
    pb = PB.Problem([prep], floors, _native.effect_vocabulary())
    chans = pb.sim_channels({}, [0], fit_only=True)[0]
    diffs = pb.slip_differences(chans)
    pairs = [(a, b) for a, b in (("omega_r", "omega_l"), ("current_r_a", "current_l_a"))
             if a in pb.fit_channels and b in pb.fit_channels]
    assert pairs and len(diffs) == len(pairs)
    for (a, b), (d, t) in zip(pairs, diffs):
        want = (chans[a].resid / floors[a] - chans[b].resid / floors[b]) / np.sqrt(2)
        assert np.allclose(d, want) and np.array_equal(t, chans[a].t)
    r0 = pb.residual({}, [0])
    assert np.sqrt(np.mean(r0 ** 2)) > 0.5        # the difference is seen
    cand = JG.evaluate_candidate(pb, ["motor_gain_asymmetry"])
    assert abs(cand.fit.values[0] - 1.15) < 0.03, cand.fit.values
    # the update's output change is counted in the difference too (without it: ~1e-9 floors)
    assert cand.output_size >= 0.5, cand.output_size
    # an unpinned stretch is no evidence for the difference either
    for c in unc:
        unc[c] = (unc[c][0], np.full(unc[c][0].size, UNPINNED_UNC))
    pb2 = PB.Problem([prep], floors, _native.effect_vocabulary())
    assert pb2.slip_differences(pb2.sim_channels({}, [0], fit_only=True)[0]) == []
