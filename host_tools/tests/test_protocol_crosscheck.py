"""C++ (lib/protocol, built by the host build recipe host_tools._build) and Python (host_tools.protocol) agree: frames
made by one are decoded by the other, and the firmware's generated validator accepts and rejects
exactly the commands that the Python side accepts and rejects."""
from __future__ import annotations

import random
import shutil
import subprocess

import pytest

from host_tools import _build
from host_tools import protocol as P

D = P.definition()

HELPER = r"""
#include <stdio.h>
#include <string.h>
#include <protocol/frame.h>
using namespace proto;
// stdin: raw wire bytes. For each verified frame: "F type seq result detail" and, for a known
// type, the frame re-encoded from the generated struct ("E hex"). Rejections: "X error".
int main() {
    Decoder d;
    int c;
    while ((c = getchar()) != EOF) {
        Decoder::Status s = d.feed(static_cast<uint8_t>(c));
        if (s == Decoder::kError) { printf("X %d\n", d.error()); continue; }
        if (s != Decoder::kFrame) continue;
        const Frame& f = d.frame();
        uint8_t detail = 0;
        Result r = validate_command(f.type, f.payload, f.len, &detail);
        printf("F %u %u %u %u\n", f.type, f.seq, r, detail);
        uint8_t out[kMaxWire];
        uint16_t n = 0;
        if (f.type == kMsgTelemetry) { Telemetry m; if (m.decode(f.payload, f.len)) n = encode_message(m, f.seq, out, sizeof out); }
        else if (f.type == kMsgParams) { Params m; if (m.decode(f.payload, f.len)) n = encode_message(m, f.seq, out, sizeof out); }
        else if (f.type == kMsgAck) { Ack m; if (m.decode(f.payload, f.len)) n = encode_message(m, f.seq, out, sizeof out); }
        else if (f.type == kMsgStart) { Start m; if (m.decode(f.payload, f.len)) n = encode_message(m, f.seq, out, sizeof out); }
        else if (f.type == kMsgSetMu) { SetMu m; if (m.decode(f.payload, f.len)) n = encode_message(m, f.seq, out, sizeof out); }
        printf("E ");
        for (uint16_t i = 0; i < n; ++i) printf("%02x", out[i]);
        printf("\n");
    }
    return 0;
}
"""


@pytest.fixture(scope="module")
def helper(tmp_path_factory):
    if shutil.which(_build.CXX) is None:
        pytest.skip(f"{_build.CXX} not installed")
    d = tmp_path_factory.mktemp("xcheck")
    (d / "main.cpp").write_text(HELPER)
    return _build.build(_build.Target("xcheck", str(d / "xcheck"),
                                      (str(d / "main.cpp"),) + _build.lib_sources("protocol")))


def run(exe, data: bytes) -> list[str]:
    return subprocess.run([str(exe)], input=data, capture_output=True, check=True).stdout.decode().splitlines()


def random_raws(msg, rnd):
    out = []
    for f in msg.fields:
        if f.type == "f32":
            out.append(rnd.choice([0.0, 0.3, -1.5, 1e-6]))
        else:
            lo, hi = P._LIMITS[f.type]
            out.append(rnd.choice([lo, hi, 0, rnd.randint(lo, hi)]))
    return tuple(out)


def test_python_frames_decode_in_cpp_and_reencode_identically(helper):
    rnd = random.Random(5)
    frames = []
    for name in ("Telemetry", "Params", "Ack", "Start", "SetMu"):
        for k in range(20):
            frames.append(D.encode_raw(name, rnd.randrange(65536), random_raws(D.by_name[name], rnd)))
    lines = run(helper, b"".join(frames))
    enc = [ln[2:] for ln in lines if ln.startswith("E ")]
    assert enc == [f.hex() for f in frames]


def test_cpp_validator_agrees_with_python(helper):
    rnd = random.Random(11)
    cases = []
    for name in ("Start", "SetMu", "SetClamp", "Stop", "Heartbeat", "RequestParams"):
        msg = D.by_name[name]
        for _ in range(300):
            raws = random_raws(msg, rnd)
            # bias towards the edges of the valid ranges
            raws = tuple((f.raw_min + rnd.choice([-1, 0, 1])) if f.raw_min is not None and rnd.random() < 0.3
                         else (f.raw_max + rnd.choice([-1, 0, 1])) if f.raw_max is not None and rnd.random() < 0.3
                         else r for f, r in zip(msg.fields, raws))
            lims = [P._LIMITS[f.type] for f in msg.fields]
            raws = tuple(min(max(r, lo), hi) for r, (lo, hi) in zip(raws, lims))
            cases.append((name, raws))
    wire = b"".join(D.encode_raw(n, i, r) for i, (n, r) in enumerate(cases))
    wire += D.frame(D.by_name["Start"].type, 9999, b"\x00\x01")  # bad length
    wire += D.frame(0x7E, 9998, b"")                              # unknown type
    lines = [ln.split() for ln in run(helper, wire) if ln.startswith("F ")]
    assert len(lines) == len(cases) + 2
    ok = D.enums["result"]["ok"]
    n_rejected = 0
    for (name, raws), (_, typ, seq, result, detail) in zip(cases, lines):
        msg = D.by_name[name]
        phys = {f.name: r * f.scale if f.scale else r for f, r in zip(msg.fields, raws)}
        try:
            D.raw_values(name, phys)
            py_ok = True
        except P.ProtocolError:
            py_ok = False
        n_rejected += not py_ok
        assert (int(result) == ok) == py_ok, (name, raws, result, detail)
        if not py_ok:
            assert int(result) == D.enums["result"]["out_of_range"]
    assert 50 < n_rejected < len(cases) - 50  # both outcomes exercised
    assert int(lines[-2][3]) == D.enums["result"]["bad_length"]
    assert int(lines[-1][3]) == D.enums["result"]["unknown_type"]
