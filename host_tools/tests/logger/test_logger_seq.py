"""The logger's count of lost frames over the robot's one frame counter: Acks and Params that
arrive while telemetry is held for confirmation (the first frames of a recording, a reset, a
jump) are no gap; a frame never received, of any kind, is counted once, across a reset and
the 16-bit wrap of seq too."""
from __future__ import annotations

import json

import pytest

from host_tools import logger as L
from host_tools import protocol as P
from test_logger import ScriptedPort, params_frame, telemetry

D = P.definition()


def ack(seq: int, cmd_seq: int = 1) -> bytes:
    return D.encode_raw("Ack", seq, (cmd_seq, D.by_name["SetClamp"].type, D.enums["result"]["ok"], 255))


def tel(seq: int, boot: int = 7, t0_us: int = 1_000_000) -> bytes:
    """Telemetry whose board time follows its seq at 20 ms (as if every frame were one)."""
    return telemetry(seq & 0xFFFF, (t0_us + 20_000 * seq) % 2**32, boot=boot)


def record(tmp_path, frames: list[bytes]) -> tuple[L.Logger, list[dict]]:
    """The logger's frame layer over the frames as one byte stream, read in odd chunks."""
    out = tmp_path / "run"
    port = ScriptedPort(b"".join(frames), [37, 200, 61])
    lg = L.Logger(str(out), lambda: port, "scripted", 115200, params_timeout_s=0.0, status=False)
    assert lg.run() == 0
    with open(out / "events.jsonl") as fh:
        return lg, [json.loads(line) for line in fh]


def gaps(ev: list[dict]) -> list[tuple[int, int, int]]:
    return [(e["after_seq"], e["seq"], e["missing"]) for e in ev if e["kind"] == "gap"]


# the start of the firmware-in-the-loop recording (/tmp/anstart/bad1): Params, then each reply
# owed before the next telemetry while the first telemetry frames wait for confirmation
START = [params_frame(0), tel(1), ack(2), tel(3), ack(4), params_frame(5), tel(6), ack(7)]


def test_replies_while_the_first_telemetry_is_held_are_no_gap(tmp_path):
    lg, ev = record(tmp_path, START + [tel(s) for s in range(8, 20)])
    assert gaps(ev) == []
    assert lg.stats["gaps"] == 0 and lg.stats["lost_frames"] == 0
    assert lg.stats["telemetry_rows"] == 15 and lg.stats["duplicates"] == 0
    assert [e["cmd_seq"] for e in ev if e["kind"] == "ack"] == [1, 1, 1]


@pytest.mark.parametrize("lost", [2, 3, 4, 5, 7, 8, 12])  # an Ack, Telemetry, Params, ...
def test_a_frame_never_received_is_counted_once_whatever_its_kind(tmp_path, lost):
    stream = START + [tel(8), tel(9), tel(10), tel(11), ack(12), tel(13), tel(14)]
    seqs = [P.StreamDecoder().feed(fr)[0].seq for fr in stream]
    lg, ev = record(tmp_path, [fr for fr, s in zip(stream, seqs) if s != lost])
    assert lg.stats["gaps"] == 1 and lg.stats["lost_frames"] == 1
    ((after, seq, missing),) = gaps(ev)
    assert (after, seq, missing) == (lost - 1, lost + 1, 1)


@pytest.mark.parametrize("lost", [None, 10, 11, 12, 13, 15])
def test_replies_while_a_jump_is_held_are_no_gap_and_a_lost_one_counts_once(tmp_path, lost):
    """A jump (board time far ahead) is held until two frames confirm it; the Acks between
    them are counted in the order they came."""
    a = [(s, tel(s)) for s in range(10)]
    b = [(s, ack(s) if s in (11, 13) else tel(s, t0_us=60_000_000)) for s in range(10, 20)]
    lg, ev = record(tmp_path, [fr for s, fr in a + b if s != lost])  # 59 s later on the board
    if lost is None:
        assert gaps(ev) == [] and lg.stats["lost_frames"] == 0
    else:
        assert gaps(ev) == [(lost - 1, lost + 1, 1)] and lg.stats["lost_frames"] == 1
    assert lg.stats["telemetry_rows"] == 10 + 8 - (lost not in (None, 11, 13))


def test_replies_while_an_implausible_frame_is_held_are_no_gap(tmp_path):
    """A frame with a bogus boot number starts a chain that the next frame refutes: it is
    flagged (received), the Ack after it is counted after it, nothing is lost."""
    bogus = tel(5, boot=99)
    lg, ev = record(tmp_path, [tel(s) for s in range(5)] + [bogus, ack(6)] + [tel(s) for s in range(7, 15)])
    assert lg.stats["implausible"] == 1
    assert gaps(ev) == [] and lg.stats["lost_frames"] == 0


def test_across_a_reset_a_frame_lost_after_it_counts_once(tmp_path):
    old = [tel(s, boot=3) for s in range(12)]
    new = [params_frame(0), tel(1, boot=4, t0_us=0), ack(2), tel(3, boot=4, t0_us=0),
           ack(4), tel(5, boot=4, t0_us=0), tel(6, boot=4, t0_us=0)]
    after = [tel(s, boot=4, t0_us=0) for s in range(8, 14)]  # seq 7 lost
    lg, ev = record(tmp_path, old + new + after)
    assert lg.stats["robot_resets"] == 1
    assert gaps(ev) == [(6, 8, 1)] and lg.stats["lost_frames"] == 1 and lg.stats["gaps"] == 1


@pytest.mark.parametrize("lost", [None, 0xFFFF, 0, 1])
def test_seq_wrap_with_replies_while_held(tmp_path, lost):
    """The first frames of the recording held across 0xFFFF -> 0, with Acks in between."""
    base = 0xFFFA
    kinds = ["P", "T", "A", "T", "A", "T", "A", "T", "T", "T", "T", "T"]
    stream = []
    for i, k in enumerate(kinds):
        s = (base + i) & 0xFFFF
        if s == lost:
            continue
        stream.append(params_frame(s) if k == "P" else ack(s) if k == "A" else tel(base + i))
    lg, ev = record(tmp_path, stream)
    if lost is None:
        assert gaps(ev) == [] and lg.stats["lost_frames"] == 0
    else:
        assert gaps(ev) == [((lost - 1) & 0xFFFF, (lost + 1) & 0xFFFF, 1)]
        assert lg.stats["lost_frames"] == 1 and lg.stats["gaps"] == 1
