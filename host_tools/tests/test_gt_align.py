"""Ground truth aligned to a recorded run (issue 23 item 5): the firmware in the loop records
runs whose ground truth is on the board clock; the tests hand the tracker's samples back on a
clock shifted by a known 3.2 s (or stamped with the host's Unix clock, the exact path) and
check the offset ``log --attach-groundtruth`` finds, its stated uncertainty and its refusals.
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from host_tools import fil
from host_tools import logger as L
from host_tools import runfmt

SHIFT_S = 3.2      # the tracker's clock: t_tracker = t_board - SHIFT_S
FRAME_S = 0.01     # the simulated tracker's frame (--cam-rate 100)
MOCAP = ["--cam-rate", "100", "--cam-noise-xy", "0.0002"]  # a motion-capture system: 0.2 mm noise


def _record(out: Path, elf, experiment: dict | None, sim_args: list[str], record_s: float | None = None):
    code, lg, _ = fil.record(out, elf, experiment, clamp=False, args=sim_args, record_s=record_s)
    assert code == 0, lg.end_reason
    return out


@pytest.fixture(scope="module")
def runs(elf, sim, tmp_path_factory):
    base = tmp_path_factory.mktemp("gt")
    unix_csv = base / "tracker-unix.csv"
    return {
        "figure_eight": _record(base / "f8", elf, {"profile": "figure_eight", "wheel_accel": 24.0,
                                                   "accel_time": 0.5, "duration": 4.0, "radius": 0.5},
                                MOCAP + ["--cam-unix-csv", str(unix_csv)]),
        "straight": _record(base / "s24", elf, {"profile": "straight", "wheel_accel": 24.0,
                                                "accel_time": 0.5, "duration": 2.0, "radius": 0.0}, MOCAP),
        "still": _record(base / "still", elf, None, MOCAP, record_s=2.0),
        "unix_csv": unix_csv,
    }


def _args(argv):
    import argparse
    p = argparse.ArgumentParser()
    L.add_arguments(p)
    return p.parse_args(argv)


def _without_groundtruth(run: Path, dst: Path) -> Path:
    dst.mkdir()
    for f in ("meta.json", "telemetry.csv"):
        shutil.copy(run / f, dst / f)
    return dst


def _tracker(run: Path, path: Path, shift_s: float = SHIFT_S, noise_m: float = 0.0) -> Path:
    gt = runfmt.load_run(run, check_units=False).groundtruth
    rng = np.random.default_rng(5)
    x = gt["x_m"] + rng.normal(0, noise_m, gt["x_m"].size) if noise_m else gt["x_m"]
    y = gt["y_m"] + rng.normal(0, noise_m, gt["y_m"].size) if noise_m else gt["y_m"]
    with open(path, "w") as fh:
        fh.write("t_s,x_m,y_m,phi_rad\n")
        for row in zip(gt["t_s"] - shift_s, x, y, gt["phi_rad"]):
            fh.write("%.6f,%.6f,%.6f,%.6f\n" % row)
    return path


@pytest.mark.parametrize("name", ["figure_eight", "straight"])
def test_a_known_shift_is_found_within_its_uncertainty_and_one_frame(runs, name, tmp_path, capsys):
    run = _without_groundtruth(runs[name], tmp_path / "run")
    trk = _tracker(runs[name], tmp_path / "tracker.csv")
    assert L.main(_args(["--out", str(run), "--attach-groundtruth", str(trk)])) == 0
    printed = capsys.readouterr().out
    info = json.loads((run / "meta.json").read_text())["groundtruth"]
    err = info["offset_s"] - SHIFT_S
    print(f"{name}: offset error {err * 1000:+.2f} ms, standard error {info.get('offset_se_s')} s")
    assert abs(err) < FRAME_S
    se = info["offset_se_s"]
    assert "+-" in printed and f"{se * 1000:.1f} ms" in printed
    assert abs(err) <= 2.5 * se  # a 99 % interval: one realisation of the camera noise per run
    assert info["tracker_frame_s"] == pytest.approx(FRAME_S)
    gt = runfmt.load_run(run, check_units=False).groundtruth
    truth = runfmt.load_run(runs[name], check_units=False).groundtruth
    assert np.abs(gt["t_s"] - truth["t_s"]).max() < FRAME_S


def test_a_robot_standing_still_is_refused_and_nothing_written(runs, tmp_path, capsys):
    run = _without_groundtruth(runs["still"], tmp_path / "run")
    meta = (run / "meta.json").read_text()
    trk = _tracker(runs["still"], tmp_path / "tracker.csv")
    assert L.main(_args(["--out", str(run), "--attach-groundtruth", str(trk)])) == 2
    err = capsys.readouterr().err
    assert "never moves" in err and "--gt-offset" in err
    assert not (run / "groundtruth.csv").exists()
    assert (run / "meta.json").read_text() == meta


def test_data_that_cannot_pin_a_frame_is_refused_unless_forced(runs, tmp_path, capsys):
    """A tracker with 3 mm noise: the start from rest leaves the offset uncertain by more than
    one frame, so nothing is written; --gt-offset forces a given offset."""
    run = _without_groundtruth(runs["figure_eight"], tmp_path / "run")
    trk = _tracker(runs["figure_eight"], tmp_path / "tracker.csv", noise_m=0.003)
    assert L.main(_args(["--out", str(run), "--attach-groundtruth", str(trk)])) == 2
    err = capsys.readouterr().err
    assert "cannot pin the clock offset within one tracker frame" in err and "--gt-offset" in err
    assert not (run / "groundtruth.csv").exists()
    assert "groundtruth" not in json.loads((run / "meta.json").read_text())
    assert L.main(_args(["--out", str(run), "--attach-groundtruth", str(trk), "--gt-offset", str(SHIFT_S)])) == 0
    assert json.loads((run / "meta.json").read_text())["groundtruth"]["method"] == "given"


def test_the_exact_path_one_host_clock(runs, tmp_path, capsys):
    """The simulator stamps its tracker samples with the host's Unix clock as they are made (a
    motion-capture client on the logging PC); the logger stamps each frame in the same clock."""
    run = _without_groundtruth(runs["figure_eight"], tmp_path / "run")
    assert L.main(_args(["--out", str(run), "--attach-groundtruth", str(runs["unix_csv"]),
                         "--gt-unix-time"])) == 0
    assert "+-" in capsys.readouterr().out
    info = json.loads((run / "meta.json").read_text())["groundtruth"]
    aligned = runfmt.load_run(run, check_units=False).groundtruth["t_s"]
    truth = runfmt.load_run(runs["figure_eight"], check_units=False).groundtruth["t_s"]
    err = float(np.median(aligned - truth))  # each sample's stamp scatters with the pacing
    print(f"host clock: offset error {err * 1000:+.2f} ms, standard error {info['offset_se_s'] * 1000:.2f} ms")
    assert abs(err) < FRAME_S
    assert abs(err) <= 2.5 * info["offset_se_s"]


def test_a_repeated_motion_without_its_start_is_refused_as_ambiguous(tmp_path, capsys):
    """Stop and go every second, the tracker switched on after the start: the speed correlation
    peaks once a period, nearly equally; the offset cannot be told, so nothing is written."""
    run = tmp_path / "run"
    t = np.arange(0, 12, 0.02)
    v = np.where((t > 1.0) & ((t % 1.0) < 0.5), 0.4, 0.0)
    x = np.cumsum(v) * 0.02
    counts = np.round(x / (2 * np.pi * runfmt.DEFAULT_META["robot"]["r"]) * runfmt.DEFAULT_META["encoder_ppr"])
    with runfmt.RunWriter(str(run), {"experiment": "stop and go"}) as w:
        for i in range(t.size):
            w.write_row({**{c: 0 for c in runfmt.TELEMETRY_COLUMNS}, "t_s": t[i], "enc_r": counts[i],
                         "enc_l": counts[i], "x_odo_m": x[i]})
    rng = np.random.default_rng(2)
    tt = np.arange(4.0, 10.0, 0.01)  # board time; the tracker's clock is SHIFT_S behind
    trk = tmp_path / "tracker.csv"
    trk.write_text("t_s,x_m,y_m\n" + "".join(
        f"{a - SHIFT_S:.4f},{b:.5f},{c:.5f}\n"
        for a, b, c in zip(tt, np.interp(tt, t, x) + rng.normal(0, 0.0005, tt.size), rng.normal(0, 0.0005, tt.size))))
    assert L.main(_args(["--out", str(run), "--attach-groundtruth", str(trk)])) == 2
    err = capsys.readouterr().err
    assert "ambiguous" in err and "--gt-offset" in err
    assert not (run / "groundtruth.csv").exists()


def test_a_recording_that_starts_in_motion_is_refused(runs, tmp_path, capsys):
    """The telemetry's first frame finds the wheels turning: the start from rest is not in the
    recording, so there is nothing to align by."""
    run = _without_groundtruth(runs["figure_eight"], tmp_path / "run")
    lines = (run / "telemetry.csv").read_text().splitlines()
    header = lines[0].split(",")
    omega = [float(row.split(",")[header.index("omega_r")]) for row in lines[1:]]
    first_moving = next(i for i, w in enumerate(omega) if w > 1.0)
    (run / "telemetry.csv").write_text("\n".join([lines[0]] + lines[1 + first_moving:]) + "\n")
    trk = _tracker(runs["figure_eight"], tmp_path / "tracker.csv")
    assert L.main(_args(["--out", str(run), "--attach-groundtruth", str(trk)])) == 2
    err = capsys.readouterr().err
    assert "already turn in the first frame" in err and "--gt-offset" in err
    assert not (run / "groundtruth.csv").exists()
