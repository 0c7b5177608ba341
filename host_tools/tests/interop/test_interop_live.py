"""The live view: a Foxglove WebSocket client (``websockets``, subprotocol
foxglove.websocket.v1) subscribes to the telemetry served while a firmware-in-the-loop run is
recorded, and receives its frames; the rows it receives are rows of telemetry.csv."""
from __future__ import annotations

import asyncio
import re
import json
import struct
import threading

import numpy as np
import pytest

from host_tools import fil
from host_tools import protocol as P
from host_tools import runfmt
from host_tools.__main__ import main as cli
from host_tools.interop import live
from host_tools.logger import TelemetryColumns

# offered as a client of both protocol generations does; foxglove-sdk's server
# (0.30.3) accepts only foxglove.sdk.v1 (and .v1.1), the successor of foxglove.websocket.v1
OFFERED = ["foxglove.websocket.v1", "foxglove.sdk.v1"]
SUBPROTOCOL = "foxglove.sdk.v1"
MESSAGE_DATA = 0x01  # binary opcode of a message on a subscription


async def _client(port: int, topics: dict[str, int], want: int, timeout_s: float,
                  ready: threading.Event) -> tuple[dict, dict[str, list]]:
    """Connect, wait for the advertised channels, subscribe to ``topics`` (topic -> our
    subscription id) and collect the first ``want`` messages of each."""
    import websockets
    got: dict[str, list] = {t: [] for t in topics}
    async with websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=OFFERED) as ws:
        assert ws.subprotocol == SUBPROTOCOL
        channels: dict[str, dict] = {}
        info: dict = {}
        while not set(topics) <= set(channels):
            msg = json.loads(await asyncio.wait_for(ws.recv(), timeout_s))
            if msg["op"] == "serverInfo":
                info = msg
            elif msg["op"] == "advertise":
                channels.update({c["topic"]: c for c in msg["channels"]})
        await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": sid, "channelId": channels[t]["id"]} for t, sid in topics.items()]}))
        ready.set()
        by_sid = {sid: t for t, sid in topics.items()}
        while min(len(v) for v in got.values()) < want:
            try:
                data = await asyncio.wait_for(ws.recv(), timeout_s)
            except asyncio.TimeoutError:
                break
            if isinstance(data, bytes) and data[0] == MESSAGE_DATA:
                sid, log_time = struct.unpack_from("<IQ", data, 1)
                if len(got[by_sid[sid]]) < want:
                    got[by_sid[sid]].append((log_time, data[13:]))
    return {"info": info, "channels": channels}, got


def _run_client(port, topics, want, timeout_s=20.0):
    ready = threading.Event()
    box: dict = {}

    def target():
        try:
            box["result"] = asyncio.run(_client(port, topics, want, timeout_s, ready))
        except BaseException as exc:  # reported by the test
            box["error"] = exc
            ready.set()
    th = threading.Thread(target=target, daemon=True)
    th.start()
    assert ready.wait(timeout_s), "the client did not subscribe"
    return th, box


def test_client_receives_published_rows():
    cols = TelemetryColumns(P.definition()).columns
    pub = live.LivePublisher(port=0, columns=cols)
    try:
        assert not pub.subscribed()
        th, box = _run_client(pub.port, {"/telemetry": 1, "/odometry/pose": 2}, want=5)
        assert "error" not in box, box.get("error")
        # the server handles the subscription after the client sent it: rows published
        # before that reach no one
        assert pub.wait_subscribed(["/telemetry", "/odometry/pose"], 20.0)
        assert not pub.subscribed()  # /odometry/tf has no subscriber
        rows = [{c: float(i) * 0.01 for c in cols} for i in range(5)]
        for r in rows:
            r["phi_odo_rad"] = 0.5
            pub.publish(r)
        th.join(30)
    finally:
        pub.close()
    assert not th.is_alive(), "the client did not receive 5 messages on each topic"
    meta, got = box["result"]
    ch = meta["channels"]
    assert ch["/telemetry"]["encoding"] == "json"
    assert set(json.loads(ch["/telemetry"]["schema"])["properties"]) == set(cols)
    assert ch["/odometry/pose"]["schemaName"] == "foxglove.PoseInFrame"
    assert ch["/odometry/pose"]["encoding"] == "protobuf"
    assert [json.loads(p) for _, p in got["/telemetry"]] == rows
    assert len(got["/odometry/pose"]) == 5


def test_a_taken_port_is_bad_input(tmp_path, capsys):
    pub = live.LivePublisher(port=0)
    try:
        rc = cli(["log", "--port", "loop://", "--out", str(tmp_path / "r"), "--live",
                  str(pub.port)])
    finally:
        pub.close()
    assert rc == 2
    assert f"--live {pub.port}: cannot serve" in capsys.readouterr().err
    assert not (tmp_path / "r" / "telemetry.csv").exists()
    with pytest.raises(ValueError, match="PORT or HOST:PORT"):
        live.parse_address("localhost:http")


def test_fil_recording_is_served_live(elf, tmp_path):
    fil.build_sim()
    cols = TelemetryColumns(P.definition()).columns
    pub = live.LivePublisher(port=0, columns=cols)
    out = tmp_path / "fil_live"
    try:
        th, box = _run_client(pub.port, {"/telemetry": 1, "/odometry/tf": 2}, want=40)
        assert pub.wait_subscribed(["/telemetry", "/odometry/tf"], 20.0)
        code, lg, _ = fil.record(out, elf, {"profile": "straight", "wheel_accel": 48.0,
                                            "accel_time": 0.5, "duration": 1.0, "radius": 0.0},
                                 clamp=False, on_row=pub.publish)
        th.join(30)
    finally:
        pub.close()
    assert code == 0, lg.end_reason
    assert "error" not in box, box.get("error")
    _, got = box["result"]
    rows = [json.loads(p) for _, p in got["/telemetry"]]
    assert len(rows) == 40 and pub.published == lg.stats["telemetry_rows"] >= 40
    run = runfmt.load_run(out)
    t = run.telemetry["t_s"]
    for r in rows:  # every frame received is a row of the recording, with the same values
        i = int(np.flatnonzero(t == r["t_s"])[0])
        for c in ("enc_r", "omega_l", "pwm_r", "x_odo_m"):
            assert r[c] == run.telemetry[c][i], c
    assert any(r["omega_r"] > 0 for r in rows)
    assert len(got["/odometry/tf"]) == 40


def test_fil_record_command_serves_live(elf, tmp_path, capsys):
    out = tmp_path / "cli_live"
    rc = cli(["-v", "fil", "record", "--out", str(out), "--elf", str(elf), "--duration", "0.5",
              "--live", "0"])
    err = capsys.readouterr().err
    assert rc == 0, err
    assert re.search(r"info: live view: ws://127\.0\.0\.1:\d+", err), err
    assert runfmt.load_run(out).telemetry["t_s"].size > 20
    # a taken port: refused before anything is built or recorded
    pub = live.LivePublisher(port=0)
    try:
        rc = cli(["fil", "record", "--out", str(tmp_path / "x"), "--elf", str(elf), "--live",
                  f"127.0.0.1:{pub.port}"])
    finally:
        pub.close()
    assert rc == 2 and "cannot serve" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()
