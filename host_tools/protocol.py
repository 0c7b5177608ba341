"""Host side of the robot <-> host wire protocol, built at run time from protocol/protocol.json.

The same JSON generates the firmware's C++ header (protocol/generate.py), so the two cannot
disagree silently: host_tools/tests/test_protocol_generated.py checks the generated header, and
the tests here check frames byte for byte against the rules in protocol/README.md.

    wire : 0x00 | COBS(body) | 0x00
    body : version u8 | type u8 | seq u16 | payload | crc u16      (little-endian)
    crc  : CRC-16/CCITT-FALSE over version..payload == binascii.crc_hqx(data, 0xFFFF)
"""
from __future__ import annotations

import binascii
import json
import math
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping, NamedTuple

from host_tools import params

DEFINITION_PATH = Path(__file__).resolve().parent.parent / "protocol" / "protocol.json"

_FMT = {"u8": "B", "i8": "b", "u16": "H", "i16": "h", "u32": "I", "i32": "i", "f32": "f"}
_LIMITS = {"u8": (0, 255), "i8": (-128, 127), "u16": (0, 65535), "i16": (-32768, 32767),
           "u32": (0, 2**32 - 1), "i32": (-2**31, 2**31 - 1)}

HEADER = struct.Struct("<BBH")


class ProtocolError(ValueError):
    """Bad protocol definition, or a message/command that cannot be encoded as given."""


def crc16(data: bytes, crc: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, xorout 0)."""
    return binascii.crc_hqx(data, crc)


def cobs_encode(data: bytes) -> bytes:
    out = bytearray(len(data) + len(data) // 254 + 1)
    code_pos, o, code = 0, 1, 1
    for b in data:
        if b == 0:
            out[code_pos] = code
            code_pos, o, code = o, o + 1, 1
        else:
            out[o] = b
            o += 1
            code += 1
            if code == 0xFF:
                out[code_pos] = code
                code_pos, o, code = o, o + 1, 1
    out[code_pos] = code
    return bytes(out[:o])


def cobs_decode(block: bytes) -> bytes | None:
    """Decode one COBS block (no delimiters); None when it is not valid COBS."""
    n = len(block)
    if n == 0 or 0 in block:
        return None
    out = bytearray()
    i = 0
    while i < n:
        code = block[i]
        j = i + code
        if j > n:
            return None
        out += block[i + 1:j]
        if code != 0xFF and j < n:
            out.append(0)
        i = j
    return bytes(out)


@dataclass(frozen=True)
class Field:
    name: str
    type: str
    scale: float | None
    unit: str
    column: str
    raw_min: int | None
    raw_max: int | None
    spec: Mapping[str, Any]

    def to_raw(self, value: Any, where: str) -> int | float:
        """Physical value -> raw wire value, refusing NaN and out-of-range values."""
        if isinstance(value, bool):  # true is not 1.0 on the wire
            raise ProtocolError(f"{where}: {value!r} is not a number")
        try:
            v = float(value)
        except (TypeError, ValueError, OverflowError):
            raise ProtocolError(f"{where}: {value!r} is not a number") from None
        if not math.isfinite(v):
            raise ProtocolError(f"{where}: {v} is not a finite number")
        if self.type == "f32":
            if abs(v) > _F32_MAX:
                raise ProtocolError(f"{where}: {value!r} is beyond a 32-bit float")
            return v
        raw = v / self.scale if self.scale else v
        lo, hi = _LIMITS[self.type]
        if self.raw_min is not None:
            lo = max(lo, self.raw_min)
        if self.raw_max is not None:
            hi = min(hi, self.raw_max)
        r = int(round(raw)) if math.isfinite(raw) and abs(raw) < 2.0**63 else None
        if r is None or not lo <= r <= hi:
            s = self.scale or 1
            raise ProtocolError(f"{where}: {value!r} {self.unit} is out of range "
                                f"[{_fmt_num(lo * s)}, {_fmt_num(hi * s)}]")
        return r


_F32_MAX = 3.4028234663852886e38


def _fmt_num(x: float) -> str:
    return f"{x:.10g}"


@dataclass(frozen=True)
class Message:
    name: str
    type: int
    dir: str
    fields: tuple[Field, ...]
    struct: struct.Struct
    constraints: tuple[tuple[str, str, str], ...]
    spec: Mapping[str, Any] = field(repr=False)

    @property
    def size(self) -> int:
        return self.struct.size

    def field_names(self) -> list[str]:
        return [f.name for f in self.fields]


class Frame(NamedTuple):
    type: int
    seq: int
    payload: bytes
    offset: int  # stream offset of the frame's first encoded byte


class Definition:
    """Everything the host needs from protocol.json."""

    def __init__(self, path: str | Path = DEFINITION_PATH):
        self.path = Path(path)
        try:
            spec = json.loads(self.path.read_text(encoding="utf-8"))
        except json.JSONDecodeError as exc:
            raise ProtocolError(f"{self.path}, line {exc.lineno}, character {exc.colno}: cannot "
                                f"load the protocol definition: {exc.msg}") from None
        except RecursionError:
            raise ProtocolError(f"{self.path}: cannot load the protocol definition: JSON nested "
                                "too deeply") from None
        except (OSError, ValueError) as exc:  # unreadable, not UTF-8, an integer too long
            raise ProtocolError(f"{self.path}: cannot load the protocol definition: {exc}") from None
        try:
            self._build(spec)
        except (KeyError, TypeError, ValueError, AttributeError, IndexError, struct.error) as exc:
            raise ProtocolError(f"{self.path}: malformed protocol definition: {type(exc).__name__} {exc}") from None

    def _build(self, spec: dict) -> None:
        try:
            params.resolve_param_ranges(spec)  # "param" fields: ranges from params/params.json
        except params.TableError as exc:
            raise ValueError(str(exc)) from None
        self.spec = spec
        self.version: int = spec["version"]
        self.baud: int = spec["link"]["baud"]
        self.bits_per_byte: int = spec["link"]["bits_per_byte"]
        self.max_payload: int = spec["framing"]["max_payload"]
        self.enums: dict[str, dict[str, int]] = {k: dict(v["values"]) for k, v in spec["enums"].items()}
        self.flags: dict[str, dict[str, int]] = {k: dict(v["bits"]) for k, v in spec["flags"].items()}
        self.timing: dict = spec["timing"]
        #: the shield's current sense and the ADC that reads it (volts_per_amp, adc_bits, adc_vref_v)
        self.current_sense: dict = {k: v for k, v in spec["current_sense"].items() if k != "doc"}
        # the parameters' defaults are the parameter table's (params/params.json)
        self.robot_defaults: dict = {"robot": dict(params.ROBOT), "motor": dict(params.MOTOR),
                                     "encoder_ppr": params.ENCODER_PPR}
        self.by_type: dict[int, Message] = {}
        self.by_name: dict[str, Message] = {}
        for m in spec["messages"]:
            fields = []
            for f in m["fields"]:
                scale = f.get("scale")
                fields.append(Field(
                    name=f["name"], type=f["type"], scale=scale, unit=f.get("unit", ""),
                    column=f.get("column", f["name"]),
                    raw_min=_raw_bound(f, "min"), raw_max=_raw_bound(f, "max"), spec=f))
            cons = []
            for c in m.get("constraints", []):
                ((op, (a, b)),) = c.items()
                cons.append((op, a, b))
            msg = Message(name=m["name"], type=m["type"], dir=m["dir"], fields=tuple(fields),
                          struct=struct.Struct("<" + "".join(_FMT[f.type] for f in fields)),
                          constraints=tuple(cons), spec=m)
            if msg.type in self.by_type or msg.name in self.by_name:
                raise ProtocolError(f"{self.path}: message {msg.name} type {msg.type} defined twice")
            self.by_type[msg.type] = msg
            self.by_name[msg.name] = msg
        self.result_names = {v: k for k, v in self.enums["result"].items()}

    # ---- tasks
    def tasks(self) -> list[dict]:
        return list(self.timing["tasks"])

    # ---- encoding
    def frame(self, type_: int, seq: int, payload: bytes, version: int | None = None) -> bytes:
        if len(payload) > self.max_payload:
            raise ProtocolError(f"payload of {len(payload)} bytes exceeds {self.max_payload}")
        body = HEADER.pack(self.version if version is None else version, type_, seq & 0xFFFF) + payload
        body += struct.pack("<H", crc16(body))
        return b"\x00" + cobs_encode(body) + b"\x00"

    def raw_values(self, name: str, values: Mapping[str, Any] | None = None) -> tuple:
        """Physical values (by field name) -> raw tuple, validated against the definition's
        ranges and constraints.  Raises ProtocolError naming the field and its range."""
        msg = self.by_name[name]
        values = dict(values or {})
        unknown = set(values) - set(msg.field_names())
        if unknown:
            raise ProtocolError(f"{name}: unknown field(s) {', '.join(sorted(unknown))}; fields are "
                                f"{', '.join(msg.field_names())}")
        raws = []
        for f in msg.fields:
            if f.name not in values:
                raise ProtocolError(f"{name}.{f.name}: missing value")
            v = values[f.name]
            if "enum" in f.spec and isinstance(v, str):
                e = self.enums[f.spec["enum"]]
                if v not in e:
                    raise ProtocolError(f"{name}.{f.name}: '{v}' is not one of {', '.join(sorted(e))}")
                v = e[v]
            raws.append(f.to_raw(v, f"{name}.{f.name}"))
        by = dict(zip(msg.field_names(), raws))
        for op, a, b in msg.constraints:
            if op == "le" and not by[a] <= by[b]:
                raise ProtocolError(f"{name}: {a} ({values[a]}) must be <= {b} ({values[b]})")
        return tuple(raws)

    def encode(self, name: str, seq: int, values: Mapping[str, Any] | None = None) -> bytes:
        msg = self.by_name[name]
        return self.frame(msg.type, seq, msg.struct.pack(*self.raw_values(name, values)))

    def encode_raw(self, name: str, seq: int, raws: Iterable) -> bytes:
        msg = self.by_name[name]
        return self.frame(msg.type, seq, msg.struct.pack(*raws))

    # ---- decoding
    def unpack(self, frame: Frame) -> tuple[Message, tuple]:
        """Raw field values of a verified frame; ProtocolError on unknown type or bad length."""
        msg = self.by_type.get(frame.type)
        if msg is None:
            raise ProtocolError(f"unknown message type {frame.type} (seq {frame.seq})")
        if len(frame.payload) != msg.size:
            raise ProtocolError(f"{msg.name} (seq {frame.seq}): payload is {len(frame.payload)} bytes, "
                                f"the definition says {msg.size}")
        return msg, msg.struct.unpack(frame.payload)

    def physical(self, msg: Message, raws: tuple) -> dict[str, float | int]:
        """Raw tuple -> {field name: physical value} (scaled fields as float)."""
        out = {}
        for f, r in zip(msg.fields, raws):
            out[f.name] = r * f.scale if f.scale is not None else r
        return out

    def wire_size(self, name: str) -> int:
        body = 4 + self.by_name[name].size + 2
        return body + body // 254 + 1 + 2


def _raw_bound(f: Mapping[str, Any], key: str) -> int | None:
    if key not in f:
        return None
    return int(round(f[key] / f.get("scale", 1)))


_DEFAULT: Definition | None = None


def definition() -> Definition:
    global _DEFAULT
    if _DEFAULT is None:
        _DEFAULT = Definition()
    return _DEFAULT


# ---------------------------------------------------------------- streaming decoder

REJECT_REASONS = ("cobs", "short", "long", "crc", "version")


class StreamDecoder:
    """Feed received bytes in any chunking; get verified frames in order.

    A block between two 0x00 delimiters becomes a frame only when its COBS is valid, its length
    is within [6, max body], its CRC matches and its version is known.  Everything else is
    counted in ``rejected[reason]`` and, up to ``keep_errors``, recorded in ``errors`` as
    (stream offset, block length, reason) so the raw capture can be inspected.  Because frames
    also start with a delimiter, the frame after any garbage is always received.
    """

    def __init__(self, version: int | None = None, max_payload: int | None = None,
                 keep_errors: int = 10000):
        if version is None or max_payload is None:  # protocol.json's, never a copy of them
            d = definition()
            version = d.version if version is None else version
            max_payload = d.max_payload if max_payload is None else max_payload
        self.version = version
        self.max_body = 4 + max_payload + 2
        self._buf = b""
        self._buf_off = 0  # stream offset of _buf[0]
        self.frames = 0
        self.bytes_in = 0
        self.rejected = {r: 0 for r in REJECT_REASONS}
        self.errors: list[tuple[int, int, str]] = []
        self.keep_errors = keep_errors

    @property
    def crc_errors(self) -> int:
        return self.rejected["crc"]

    @property
    def bad_blocks(self) -> int:
        return sum(self.rejected.values())

    def _reject(self, off: int, n: int, reason: str) -> None:
        self.rejected[reason] += 1
        if len(self.errors) < self.keep_errors:
            self.errors.append((off, n, reason))

    def feed(self, data: bytes) -> list[Frame]:
        self.bytes_in += len(data)
        buf = self._buf + data if self._buf else bytes(data)
        parts = buf.split(b"\x00")
        tail = parts.pop()  # after the last delimiter: incomplete
        off = self._buf_off
        out: list[Frame] = []
        append = out.append
        max_enc = self.max_body + 1
        version = self.version
        crc_hqx = binascii.crc_hqx
        for seg in parts:
            n = len(seg)
            if n:
                if n > max_enc:
                    self._reject(off, n, "long")
                else:
                    # COBS decode: every code byte after the first marks a zero in the body.
                    # Blocks are at most max_body + 1 < 255 bytes, so a 0xFF code (a 254-byte
                    # run without zero) always overshoots the end and fails the j != n test.
                    code = seg[0]
                    if code == n:  # one block, no zero in the body (common fast path)
                        body = seg[1:]
                    else:
                        b = bytearray(seg)
                        j = code
                        while j < n:
                            c = b[j]
                            b[j] = 0
                            j += c
                        if j != n:
                            self._reject(off, n, "cobs")
                            off += n + 1
                            continue
                        body = bytes(b[1:])
                    blen = n - 1
                    if blen < 6:
                        self._reject(off, n, "short")
                    elif crc_hqx(body[:-2], 0xFFFF) != body[-2] | (body[-1] << 8):
                        self._reject(off, n, "crc")
                    elif body[0] != version:
                        self._reject(off, n, "version")
                    else:
                        append(Frame(body[1], body[2] | (body[3] << 8), body[4:-2], off))
            off += n + 1
        self.frames += len(out)
        # Keep at most one block's worth of tail: anything longer is already garbage.
        if len(tail) > max_enc + 1:
            drop = len(tail) - (max_enc + 1)
            tail = tail[drop:]
            off += drop
        self._buf = tail
        self._buf_off = off
        return out

    def pending(self) -> int:
        """Bytes received after the last delimiter (an incomplete frame)."""
        return len(self._buf)
