"""Driving the robot with velocity commands (protocol Drive, SetDriveLimits, SetModel), the host
API (host_tools.robot) and the model round trip, in the firmware in the loop.

The simulator runs at twice real time (--realtime 2) where a test drives: HostScript scripts
are timed by the board clock, the host's heartbeats keep up; Robot holds the board clock from
the simulator's start until drive() or sleep() lets it run (lockstep).  The model round trip: test_drive_roundtrip.py.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from host_tools import fil
from host_tools import params
from host_tools import protocol as P
from host_tools.robot import DriveSession, Robot, RobotError, read_path

from test_fil import HostScript, csv  # noqa: E402  (the FIL tests' host, CSV reader)

D = P.definition()
RUNNING = 1 << D.flags["status"]["running"]
DRIVE = 1 << D.flags["status"]["drive_mode"]
FAST = ["--realtime", "2"]


def test_drive_ramps_times_out_and_the_failsafe_still_brakes(elf, sim, tmp_path):
    """Drive starts drive mode; the reference ramps at the accel limit to the target and
    telemetry reports both; a Start or a SetModel while driving is busy; after cmd_timeout
    without a Drive the target is 0 (the robot ramps to rest and stays in drive mode, heartbeats
    keep it alive); when the host falls silent the host-timeout failsafe brakes."""
    steps = [
        (0.10, D.encode("SetDriveLimits", 1, {"accel": 0.5, "alpha": 4.0, "cmd_timeout": 0.6})),
        (0.20, D.encode("Drive", 2, {"linear": 0.2, "angular": 0.0})),
        (0.30, D.encode("Start", 3, {"profile": "straight", "wheel_accel": 20.0, "accel_time": 0.5,
                                     "duration": 1.0, "radius": 0.0})
         + D.encode("SetModel", 4, {"r": 0.036, "b": 0.1, "ke_ratio": 1.0, "drop_v": 0.0})),
    ] + [(0.40 + 0.1 * i, D.encode("Heartbeat", 5 + i)) for i in range(30)]
    # from board time 2.3 s no host byte reaches the robot (the simulator cuts the link)
    host = HostScript(elf, tmp_path / "timeout", ["--t-end", "4.0", "--host-silent-at", "2.3"])

    def step(now, t):
        while steps and now >= steps[0][0]:
            host.port.write(steps.pop(0)[1])
        return None if now < 3.5 else False

    host.run(step)
    acks = {q: D.result_names.get(r) for q, _, r in host.acks}
    assert acks[1] == "ok" and acks[2] == "ok"
    assert acks[3] == "busy" and acks[4] == "busy"
    run = [x for x in host.telem if int(x["status"]) & RUNNING]
    assert run and all(int(x["status"]) & DRIVE for x in run)
    v_ref = np.array([x["v_ref"] for x in run])
    v_cmd = np.array([x["v_cmd"] for x in run])
    t = np.array([x["t_us"] for x in run])
    t_start = t[0]  # within one telemetry period after the start tick, which follows the Drive
    # the ramp at 0.5 m/s^2 (the reference steps every 50 ms: at most one step ahead of the line)
    assert np.all(v_ref <= 0.5 * (t - t_start + 0.02) + 0.025 + 0.002)
    assert v_ref.max() == pytest.approx(0.2, abs=0.002)
    assert t[np.argmax(v_ref >= 0.199)] - t_start == pytest.approx(0.4, abs=0.08)
    # the timeout: the target is the Drive's until 0.6 s after it, then 0 (from the next outer tick)
    assert np.all(v_cmd[t < t_start + 0.6 - 0.08] == pytest.approx(0.2))
    assert np.all(v_cmd[t > t_start + 0.6 + 0.05 + 0.02] == 0.0)
    assert v_ref[-1] == 0.0 and t[-1] > 2.0  # ramped to rest, still in drive mode (heartbeats)
    # the host silent from 2.3 s: the failsafe brakes within 0.5 s (the first frame that reports
    # it follows within a telemetry period), and 0.5 s after the last Heartbeat the firmware
    # took, not before: on the board clock from its Ack (a host paced by telemetry it reads
    # late under load writes its Heartbeats later than the board times it meant)
    fs = [x for x in host.telem if x["failsafe"] == D.enums["failsafe"]["host_timeout"]]
    assert fs and fs[0]["t_us"] <= 2.3 + 0.5 + 0.021
    hb = D.by_name["Heartbeat"].type
    rx_t = max(t for (_, typ, r), t in zip(host.acks, host.ack_after_t)
               if typ == hb and D.result_names.get(r) == "ok" and t < fs[0]["t_us"])
    assert rx_t < 2.3 and 0.45 <= fs[0]["t_us"] - rx_t <= 0.7  # as in test_fil (junk frames)
    assert not int(fs[0]["status"]) & RUNNING


def test_set_model_is_validated_and_reported_back(elf, sim, tmp_path):
    """SetModel: out of the params.json range -> out_of_range (detail = the field); a radius
    the fixed-point controller cannot hold -> out_of_range (detail 0); a good one is reported in
    Params (r, b, ke_ratio, drop_v, the torque->duty map's motor) and changes nothing else."""
    typ = D.by_name["SetModel"].type
    lo_r = params.RANGES[("robot", "r")][0]
    steps = [
        (0.10, D.frame(typ, 10, D.by_name["SetModel"].struct.pack(int(lo_r * 1e6) - 1, int(params.ROBOT["b"] * 1e6), 10000, 0))),
        (0.15, D.encode("SetModel", 11, {"r": 0.9, "b": params.ROBOT["b"], "ke_ratio": 1.0, "drop_v": 0.0})),
        (0.20, D.encode("SetModel", 12, {"r": 0.03723, "b": 0.107, "ke_ratio": 1.2, "drop_v": 1.5})
         + D.encode("RequestParams", 13)),
    ]
    host = HostScript(elf, tmp_path / "setmodel", ["--t-end", "0.8"])

    def step(now, t):
        while steps and now >= steps[0][0]:
            host.port.write(steps.pop(0)[1])
        return None if now < 0.6 else False

    host.run(step)
    acks = {q: (D.result_names.get(r), typ_) for q, typ_, r in host.acks}
    assert acks[10] == ("out_of_range", typ)
    assert acks[11] == ("out_of_range", typ)
    assert acks[12] == ("ok", typ)
    p = host.params[-1]
    sheet = params.MOTOR
    assert p["r"] == pytest.approx(0.03723, rel=1e-6) and p["b"] == pytest.approx(0.107, rel=1e-6)
    assert p["ke_ratio"] == pytest.approx(1.2, rel=1e-6) and p["drop_v"] == pytest.approx(1.5, rel=1e-6)
    f = (sheet["supply_v"] - 1.5) / sheet["supply_v"]
    assert p["stall_nm"] == pytest.approx(sheet["stall_nm"] * f, rel=1e-5)
    assert p["no_load_rad_s"] == pytest.approx(sheet["no_load_rad_s"] * f / 1.2, rel=1e-5)
    assert p["mu_s"] == pytest.approx(params.ROBOT["mu_s"], rel=1e-6)  # unchanged


def test_log_writes_the_start_profile_as_reference(elf, sim, tmp_path):
    """fil record (the logger) writes meta.json reference: the Start profile as the firmware
    builds it (accel = r wheel_accel, cruise = accel accel_time) and t0_s, the board time of the
    run's first tick, which the analyzer's closed-loop replay needs."""
    exp = {"profile": "arc", "wheel_accel": 30.0, "accel_time": 0.5, "duration": 1.0, "radius": 0.5}
    code, lg, _ = fil.record(tmp_path / "arc", elf, exp, clamp=True, args=FAST)
    assert code == 0, lg.end_reason
    meta = json.loads((tmp_path / "arc" / "meta.json").read_text())
    ref = meta["reference"]
    r = meta["robot"]["r"]
    assert ref["kind"] == "arc" and ref["radius"] == 0.5
    assert ref["accel"] == pytest.approx(r * 30.0) and ref["cruise"] == pytest.approx(r * 15.0)
    tel = csv(tmp_path / "arc" / "telemetry.csv")
    first = np.flatnonzero(tel["status"].astype(int) & RUNNING)[0]
    # the first running frame comes within one telemetry period after the start tick
    assert 0.0 <= tel["t_s"][first] - ref["t0_s"] <= 0.021


def test_bad_port_is_one_clear_message(tmp_path):
    with pytest.raises(RobotError) as e:
        Robot("/dev/ddrobot-no-such-port", out=tmp_path / "r")
    assert e.value.code == 2 and "cannot open port /dev/ddrobot-no-such-port" in str(e.value)
    r = subprocess.run([sys.executable, "-m", "host_tools", "drive", "--port", "/dev/ddrobot-no-such-port",
                        "--out", str(tmp_path / "r2"), "--path", str(_path_file(tmp_path))],
                       capture_output=True, text=True, cwd=Path(__file__).resolve().parents[2])
    assert r.returncode == 2
    assert r.stderr.count("error:") == 1 and "cannot open port" in r.stderr


def _path_file(tmp_path: Path, text: str = "t,v,w\n0,0.1,0\n1,0,0\n") -> Path:
    p = tmp_path / "path.csv"
    p.write_text(text)
    return p


@pytest.mark.parametrize("text, where", [
    ("t,v,w\n0,0.1,0\n1,abc,0\n", "row 3, column 2"),
    ("0,0.1,0\n1,9.0,0\n", "row 2, column 2"),      # beyond Drive's range
    ("0,0.1,0\n-1,0,0\n", "row 2, column 1"),       # time going back
    ("0,0.1\n", "row 1: expected 3 columns"),
])
def test_bad_path_files_are_refused_with_row_and_column(tmp_path, text, where):
    with pytest.raises(ValueError, match=where):
        read_path(str(_path_file(tmp_path, text)))
    r = subprocess.run([sys.executable, "-m", "host_tools", "drive", "--port", "loop://",
                        "--out", str(tmp_path / "r"), "--path", str(_path_file(tmp_path, text))],
                       capture_output=True, text=True, cwd=Path(__file__).resolve().parents[2])
    assert r.returncode == 2 and where in r.stderr
    assert not (tmp_path / "r").exists()  # nothing was made


def test_robot_set_model_between_drives_is_reported_back(elf, sim, tmp_path):
    """Robot.set_model while stopped: SetMu and SetModel acknowledged, the robot's Params (and
    so meta.json) report the new wheel radius; while driving the firmware answers busy."""
    model = {"format": "ddmodel/1", "robot": dict(params.ROBOT, r=0.0371, mu_s=0.3, mu_k=0.28)}
    with Robot(fil=True, out=tmp_path / "sm", elf=elf, sim_args=FAST) as bot:
        bot.drive(0.1, 0.0)
        bot.sleep(0.3)
        with pytest.raises(RobotError, match="busy"):
            bot.set_model(model)
        bot.stop()
        bot.wait_stopped()
        bot.set_model(model)
        bot.sleep(0.2)
    meta = json.loads((tmp_path / "sm" / "meta.json").read_text())
    assert meta["robot"]["r"] == pytest.approx(0.0371) and meta["robot"]["mu_s"] == pytest.approx(0.3)
    assert [c["command"] for c in meta["commands"] if c["result"] == "ok"][-2:] == ["SetMu", "SetModel"]


def test_robot_set_model_gets_its_params_at_the_first_ask(elf, sim, tmp_path):
    """Robot.set_model's RequestParams, right behind the SetMu and SetModel Acks and telemetry,
    is answered at the first ask: the firmware keeps a reply the transmit ring has no room for
    and sends it before the next telemetry frame, so the host's re-ask (kept as a guard) never
    runs. Three set_model calls in the held simulator; one RequestParams each."""
    asks = []
    real_send = DriveSession.send

    def send(self, name, values=None):
        if name == "RequestParams":
            asks.append(name)
        return real_send(self, name, values)

    models = [{"format": "ddmodel/1", "robot": dict(params.ROBOT, r=r, mu_s=0.3, mu_k=0.28)}
              for r in (0.0371, 0.0372, 0.0373)]
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(DriveSession, "send", send)
        with Robot(fil=True, out=tmp_path / "sm", elf=elf, sim_args=FAST) as bot:
            n0 = len(asks)
            for m in models:
                bot.set_model(m)
            n = len(asks) - n0
    events = (tmp_path / "sm" / "events.jsonl").read_text()
    print(f"\n{len(models)} set_model: {n} RequestParams sent")
    assert "no_params_after_config" not in events
    assert n == len(models)
    meta = json.loads((tmp_path / "sm" / "meta.json").read_text())
    assert meta["robot"]["r"] == pytest.approx(0.0373)


def _lockstep_drive(elf, out, path, stall_at=None, stall_s=0.0, model=None):
    """drive_path in the firmware in the loop (``model``: set_model first); ``stall_at``:
    before that command of the drive, and before the start-up's SetDriveLimits and set_model's
    SetModel, the host stalls for ``stall_s`` wall seconds. Returns (meta.json, telemetry
    during the drive)."""
    import time
    sends = []
    real_send = Robot._send_written
    real_command = DriveSession.command

    def send(self, name, vw):
        if len(sends) == stall_at:
            time.sleep(stall_s)
        sends.append(name)
        real_send(self, name, vw)

    def command(self, name, values=None):
        if name in ("SetDriveLimits", "SetModel") and stall_at is not None:
            time.sleep(stall_s)
        return real_command(self, name, values)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(Robot, "_send_written", send)
        mp.setattr(DriveSession, "command", command)
        with Robot(fil=True, out=out, elf=elf, sim_args=FAST) as bot:
            if model is not None:
                bot.set_model(model)
            bot.drive_path(path)
    assert bot.code == 0, bot.session.end_reason
    meta = json.loads((out / "meta.json").read_text())
    tel = csv(out / "telemetry.csv")
    t0 = meta["reference"]["t0_s"]
    during = (tel["t_s"] >= t0) & (tel["t_s"] <= t0 + path[-1][0])
    return meta, {k: v[during] for k, v in tel.items()}


def test_drive_path_in_the_loop_is_on_the_board_clock_whatever_the_host(elf, sim, tmp_path):
    """In the firmware in the loop the host holds the board clock (--lockstep) from the
    simulator's start: each row is the target of the outer tick at t0 + t exactly, and a host
    that stalls for 0.4 s of wall time during its start-up (before SetDriveLimits), in
    set_model (before SetModel) and before a command of the drive changes nothing (on a
    free-running simulator at --realtime 2 each stall would be 0.8 s of board time: the drive
    would start later, and the command would land past the 0.5 s command timeout): no
    failsafe, the drive starts at the same board time, it is the same drive, frame for frame,
    and the whole recording, start-up included, is the same bytes."""
    path = [(0.0, 0.0, 0.0), (0.1, 0.2, 0.0), (0.5, 0.2, 1.0), (0.9, 0.0, 0.0), (1.4, 0.0, 0.0)]
    model = {"format": "ddmodel/1", "robot": dict(params.ROBOT, r=0.0371, mu_s=0.3, mu_k=0.28)}
    meta_a, a = _lockstep_drive(elf, tmp_path / "a", path, model=model)
    meta_b, b = _lockstep_drive(elf, tmp_path / "b", path, stall_at=8, stall_s=0.4, model=model)
    for meta in (meta_a, meta_b):
        ref = meta["reference"]
        assert ref["runs"] == 1 and ref["ambiguous"] == 0
        got = [(round(c["t_s"] - ref["t0_s"], 6), c["v"], c["omega"]) for c in ref["commands"]]
        assert got == [(0.0, 0.0, 0.0), (0.1, 0.2, 0.0), (0.5, 0.2, 1.0), (0.9, 0.0, 0.0)]
        assert meta["fil"]["summary"]["link"]["down_frames"] > 0
    assert set(a["failsafe"].astype(int)) == {0} and set(b["failsafe"].astype(int)) == {0}
    t0a, t0b = meta_a["reference"]["t0_s"], meta_b["reference"]["t0_s"]
    print(f"\nlockstep drive: t0 {t0a} s without a stall, {t0b} s with 3 x 0.4 s of host stalls")
    assert t0a == t0b  # the drive starts on the same board time (the firmware's start-up withheld)
    assert a["t_s"].size > 60
    for k in ("t_s", "enc_r", "enc_l", "x_odo_m", "y_odo_m", "phi_odo_rad", "tau_cmd_r", "tau_cmd_l",
              "pwm_r", "pwm_l", "v_ref_m_s", "omega_ref_rad_s"):
        assert np.array_equal(a[k], b[k]), k
    for meta in (meta_a, meta_b):  # set_model took effect (while held, its Acks granted time)
        assert meta["robot"]["r"] == pytest.approx(0.0371)
    for f in ("raw.bin", "groundtruth.csv", "plant.csv"):
        assert (tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes(), f


def test_drive_paths_one_after_another_in_the_loop(elf, sim, tmp_path):
    """After a drive_path the simulator stays held (the recording, if closed now, ends at the
    same board time in every run); a second drive_path goes on from the hold, and sleep() lets
    the clock run free again, heartbeats on the wall clock keeping the link."""
    path = [(0.0, 0.0, 0.0), (0.1, 0.2, 0.0), (0.4, 0.0, 0.0), (0.8, 0.0, 0.0)]
    with Robot(fil=True, out=tmp_path / "two", elf=elf, sim_args=FAST) as bot:
        bot.drive_path(path)
        assert bot._sim.stepping
        bot.drive_path(path)
        bot.sleep(1.0)  # free running: 1 s of board time without a Drive, heartbeats only
        assert not bot._sim.stepping
    assert bot.code == 0, bot.session.end_reason
    meta = json.loads((tmp_path / "two" / "meta.json").read_text())
    assert meta["reference"]["runs"] == 2
    tel = csv(tmp_path / "two" / "telemetry.csv")
    assert set(tel["failsafe"].astype(int)) <= {0, D.enums["failsafe"]["stopped_by_host"]}
    assert tel["t_s"][-1] - tel["t_s"][0] > 3.0
