"""host_tools.protocol: CRC, COBS, frames, command validation, the streaming decoder (incl. a
hypothesis fuzz: no crash, and no corrupt frame ever returned as valid)."""
from __future__ import annotations

import math
import random
import struct

import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from host_tools import protocol as P

D = P.definition()
FUZZ = settings(max_examples=300, derandomize=True, deadline=None,
                suppress_health_check=[HealthCheck.too_slow])


def telemetry_raw(i: int = 0) -> tuple:
    msg = D.by_name["Telemetry"]
    rnd = random.Random(i)
    vals = []
    for f in msg.fields:
        lo, hi = P._LIMITS[f.type]
        vals.append(rnd.choice([0, 1, lo, hi, rnd.randint(lo, hi)]))
    return tuple(vals)


def test_crc_is_ccitt_false():
    assert P.crc16(b"123456789") == 0x29B1
    # independent bitwise reference
    def ref(data):
        crc = 0xFFFF
        for b in data:
            crc ^= b << 8
            for _ in range(8):
                crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
        return crc
    rnd = random.Random(1)
    for n in (0, 1, 5, 100):
        data = bytes(rnd.randrange(256) for _ in range(n))
        assert P.crc16(data) == ref(data)


@pytest.mark.parametrize("raw,enc", [
    (b"\x00", b"\x01\x01"), (b"\x00\x00", b"\x01\x01\x01"),
    (b"\x11\x22\x00\x33", b"\x03\x11\x22\x02\x33"), (b"\x11\x22\x33\x44", b"\x05\x11\x22\x33\x44"),
    (bytes(range(1, 255)), b"\xff" + bytes(range(1, 255)) + b"\x01"),
])
def test_cobs_vectors(raw, enc):
    assert P.cobs_encode(raw) == enc
    assert P.cobs_decode(enc) == raw


@given(st.binary(max_size=700))
@FUZZ
def test_cobs_round_trip(data):
    enc = P.cobs_encode(data)
    assert 0 not in enc
    assert P.cobs_decode(enc) == data


def test_frame_layout_by_hand():
    payload = bytes([1, 0x34, 0x12])
    w = D.frame(0x42, 0x0102, payload)
    body = bytes([D.version, 0x42, 0x02, 0x01]) + payload
    body += struct.pack("<H", P.crc16(body))
    assert w == b"\x00" + P.cobs_encode(body) + b"\x00"


def test_every_message_round_trips():
    dec = P.StreamDecoder()
    for name, msg in D.by_name.items():
        raws = telemetry_raw(7) if name == "Telemetry" else tuple(
            0.5 if f.type == "f32" else (f.raw_min or 0) for f in msg.fields)
        w = D.encode_raw(name, 1234, raws)
        assert len(w) == D.wire_size(name)
        (fr,) = dec.feed(w)
        m, got = D.unpack(fr)
        assert m.name == name and fr.seq == 1234
        assert got == raws


def test_physical_scaling_of_telemetry():
    msg = D.by_name["Telemetry"]
    names = msg.field_names()
    raws = [0] * len(names)
    raws[names.index("omega_r")] = 3512
    raws[names.index("x_odo")] = -1234567
    raws[names.index("inner_max")] = 100
    phys = D.physical(msg, tuple(raws))
    assert phys["omega_r"] == pytest.approx(35.12)
    assert phys["x_odo"] == pytest.approx(-1.234567)
    assert phys["inner_max"] == 1600  # cycles


def test_command_validation_names_field_and_range():
    ok = {"profile": "straight", "wheel_accel": 48, "accel_time": 0.5, "duration": 3, "radius": 0}
    D.encode("Start", 0, ok)
    with pytest.raises(P.ProtocolError, match=r"Start\.wheel_accel: 250 rad/s\^2 is out of range \[0\.01, 200\]"):
        D.encode("Start", 0, dict(ok, wheel_accel=250))
    with pytest.raises(P.ProtocolError, match=r"Start\.radius: nan is not a finite number"):
        D.encode("Start", 0, dict(ok, radius=math.nan))
    with pytest.raises(P.ProtocolError, match=r"accel_time .* must be <= duration"):
        D.encode("Start", 0, dict(ok, accel_time=5, duration=2))
    with pytest.raises(P.ProtocolError, match=r"profile: 'spiral' is not one of"):
        D.encode("Start", 0, dict(ok, profile="spiral"))
    with pytest.raises(P.ProtocolError, match=r"missing value"):
        D.encode("SetMu", 0, {"mu_s": 0.3})
    with pytest.raises(P.ProtocolError, match=r"SetClamp\.on: 2 .*out of range \[0, 1\]"):
        D.encode("SetClamp", 0, {"on": 2})


def test_decoder_resyncs_after_garbage_and_counts():
    good = [D.encode_raw("Telemetry", i, telemetry_raw(i)) for i in range(5)]
    stream = good[0] + b"\x13\x37\xff\x10" + good[1] + good[2][:40] + good[3] + b"\x00\x00" + good[4]
    dec = P.StreamDecoder()
    frames = dec.feed(stream)
    assert [f.seq for f in frames] == [0, 1, 3, 4]  # frame 2 was cut short by a reset
    assert dec.bad_blocks == 2
    assert len(dec.errors) == 2


def test_decoder_long_garbage_without_delimiter_is_bounded():
    dec = P.StreamDecoder()
    for _ in range(100):
        assert dec.feed(bytes(range(1, 256)) * 4) == []
    assert dec.pending() <= 200
    w = D.encode_raw("Telemetry", 9, telemetry_raw(9))
    (f,) = dec.feed(w)
    assert f.seq == 9
    assert dec.rejected["long"] == 1


@given(st.lists(st.integers(min_value=1, max_value=64), min_size=1, max_size=60))
@FUZZ
def test_chunking_does_not_matter(chunks):
    stream = b"".join(D.encode_raw("Telemetry", i, telemetry_raw(i)) for i in range(8))
    dec = P.StreamDecoder()
    got, pos, k = [], 0, 0
    while pos < len(stream):
        n = chunks[k % len(chunks)]
        got += dec.feed(stream[pos:pos + n])
        pos += n
        k += 1
    assert [f.seq for f in got] == list(range(8))
    assert [f.offset for f in got] == [i * D.wire_size("Telemetry") + 1 for i in range(8)]


@st.composite
def corrupted_streams(draw):
    n = draw(st.integers(min_value=1, max_value=6))
    frames = [D.encode_raw("Telemetry", draw(st.integers(0, 65535)), telemetry_raw(draw(st.integers(0, 999))))
              for _ in range(n)]
    stream = bytearray(b"".join(frames))
    for _ in range(draw(st.integers(min_value=0, max_value=8))):
        op = draw(st.sampled_from(["flip", "set", "drop", "insert", "dup"]))
        if not stream:
            break
        i = draw(st.integers(0, len(stream) - 1))
        if op == "flip":
            stream[i] ^= 1 << draw(st.integers(0, 7))
        elif op == "set":
            stream[i] = draw(st.integers(0, 255))
        elif op == "drop":
            del stream[i:i + draw(st.integers(1, 30))]
        elif op == "insert":
            stream[i:i] = draw(st.binary(min_size=1, max_size=40))
        else:
            j = draw(st.integers(i, min(len(stream), i + 120)))
            stream[i:i] = stream[i:j]
    split = draw(st.integers(0, len(stream)))
    return frames, bytes(stream), split


@given(corrupted_streams())
@FUZZ
def test_fuzz_no_crash_and_nothing_false_accepted(case):
    frames, stream, split = case
    sent = {bytes(f) for f in frames}
    dec = P.StreamDecoder()
    got = dec.feed(stream[:split]) + dec.feed(stream[split:])
    for f in got:
        # every accepted frame is byte-for-byte one that was sent
        assert D.frame(f.type, f.seq, f.payload) in sent
        D.unpack(f)
    assert dec.frames == len(got)


@given(st.binary(min_size=0, max_size=90), st.lists(st.integers(0, 10_000), min_size=1, max_size=3, unique=True))
@FUZZ
def test_up_to_three_bit_errors_are_always_detected(payload, bits):
    """CRC-16/CCITT-FALSE has Hamming distance 4 at these lengths: any 1-3 flipped bits of
    the body (header, payload or CRC), even after COBS re-encoding, must be rejected."""
    body = bytearray(struct.pack("<BBH", D.version, 1, 77) + payload)
    body += struct.pack("<H", P.crc16(bytes(body)))
    for b in bits:
        b %= len(body) * 8
        body[b // 8] ^= 1 << (b % 8)
    if len(set(b % (len(body) * 8) for b in bits)) != len(bits):
        return  # two flips cancelled
    wire = b"\x00" + P.cobs_encode(bytes(body)) + b"\x00"
    dec = P.StreamDecoder()
    assert dec.feed(wire) == []
    assert dec.bad_blocks == 1


@given(st.binary(max_size=2000))
@FUZZ
def test_fuzz_random_bytes(data):
    dec = P.StreamDecoder()
    for f in dec.feed(data):
        assert D.frame(f.type, f.seq, f.payload)[1:-1] == data[f.offset:f.offset + len(D.frame(f.type, f.seq, f.payload)) - 2]


def test_malformed_definition_is_a_clear_error(tmp_path):
    import json

    d = json.loads(P.DEFINITION_PATH.read_text())
    del d["messages"][0]["fields"][0]["type"]
    p = tmp_path / "p.json"
    p.write_text(json.dumps(d))
    with pytest.raises(P.ProtocolError, match=r"malformed protocol definition: KeyError 'type'"):
        P.Definition(p)
    p.write_text("{")
    with pytest.raises(P.ProtocolError, match="cannot load the protocol definition"):
        P.Definition(p)
