#!/usr/bin/env python3
"""Generate the C++ message header (and the message tables) from protocol/protocol.json.

    python3 protocol/generate.py          # rewrite the generated files
    python3 protocol/generate.py --check  # exit 1 if a committed file differs (drift test)

Outputs:
    lib/protocol/src/protocol/messages.h  -- structs, encode/decode, validators, constants
    protocol/messages.md                  -- field tables, sizes and the link budget

host_tools/protocol.py reads protocol.json directly, with the same layout rules as below
(fields packed in order, little-endian, no padding).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DEFINITION = ROOT / "protocol" / "protocol.json"
HEADER = ROOT / "lib" / "protocol" / "src" / "protocol" / "messages.h"
TABLES = ROOT / "protocol" / "messages.md"

# type -> (C type, size, min, max, put/get suffix)
TYPES = {
    "u8": ("uint8_t", 1, 0, 255),
    "i8": ("int8_t", 1, -128, 127),
    "u16": ("uint16_t", 2, 0, 65535),
    "i16": ("int16_t", 2, -32768, 32767),
    "u32": ("uint32_t", 4, 0, 4294967295),
    "i32": ("int32_t", 4, -2147483648, 2147483647),
    "f32": ("float", 4, None, None),
}


class DefinitionError(ValueError):
    pass


def camel(name: str) -> str:
    return "".join(part[:1].upper() + part[1:] for part in name.split("_"))


def load(path: Path = DEFINITION) -> dict:
    with open(path, encoding="utf-8") as f:
        defn = json.load(f)
    # fields with "param": their range is params/params.json's (the one table of the parameters)
    sys.path.insert(0, str(ROOT))
    from host_tools import params as param_table  # stdlib only
    param_table.resolve_param_ranges(defn)
    check(defn)
    return defn


def payload_size(msg: dict) -> int:
    return sum(TYPES[f["type"]][1] for f in msg["fields"])


def raw_bound(field: dict, key: str) -> int | None:
    """Physical min/max of a field converted to its raw integer (exactly representable)."""
    if key not in field:
        return None
    scale = field.get("scale", 1)
    raw = field[key] / scale
    if abs(raw - round(raw)) > 1e-6 * max(1.0, abs(raw)):
        raise DefinitionError(f"{field['name']}.{key}={field[key]} is not a multiple of scale {scale}")
    return int(round(raw))


def current_scale(defn: dict) -> float:
    """Amperes per raw count of the current sense (protocol.json current_sense)."""
    cs = defn["current_sense"]
    return cs["adc_vref_v"] / 2 ** cs["adc_bits"] / cs["volts_per_amp"]


def check(defn: dict) -> None:
    types_seen: dict[int, str] = {}
    amps = current_scale(defn)
    for msg in defn["messages"]:
        for f in msg["fields"]:
            if f.get("unit") == "A" and abs(f.get("scale", 1) / amps - 1) > 1e-4:
                raise DefinitionError(f"{msg['name']}.{f['name']}: scale {f.get('scale')} is not current_sense's "
                                      f"{amps:.7g} A per count")
    for t in defn["timing"]["tasks"]:
        if t["period_us"] % defn["timing"]["sched_tick_us"]:
            raise DefinitionError(f"task {t['name']}: period_us {t['period_us']} is not a whole number of "
                                  f"sched_tick_us {defn['timing']['sched_tick_us']}")
    maxp = defn["framing"]["max_payload"]
    if defn["framing"]["header_bytes"] + maxp + defn["framing"]["crc_bytes"] >= 254:
        raise DefinitionError("max body must stay below 254 bytes (one COBS block)")
    for msg in defn["messages"]:
        t = msg["type"]
        if not 0 < t < 256 or t in types_seen:
            raise DefinitionError(f"message {msg['name']}: type {t} invalid or reused ({types_seen.get(t)})")
        types_seen[t] = msg["name"]
        if msg["dir"] not in ("robot_to_host", "host_to_robot"):
            raise DefinitionError(f"message {msg['name']}: bad dir {msg['dir']!r}")
        if payload_size(msg) > maxp:
            raise DefinitionError(f"message {msg['name']}: payload {payload_size(msg)} > max_payload {maxp}")
        names = set()
        for f in msg["fields"]:
            if f["type"] not in TYPES:
                raise DefinitionError(f"{msg['name']}.{f['name']}: unknown type {f['type']}")
            if f["name"] in names:
                raise DefinitionError(f"{msg['name']}.{f['name']}: duplicate field")
            names.add(f["name"])
            for key in ("enum", "flags"):
                if key in f and f[key] not in defn[key + "s" if key == "enum" else key]:
                    raise DefinitionError(f"{msg['name']}.{f['name']}: unknown {key} {f[key]}")
            lo, hi = raw_bound(f, "min"), raw_bound(f, "max")
            tmin, tmax = TYPES[f["type"]][2], TYPES[f["type"]][3]
            if tmin is not None:
                if lo is not None and lo < tmin or hi is not None and hi > tmax:
                    raise DefinitionError(f"{msg['name']}.{f['name']}: range does not fit {f['type']}")
        for c in msg.get("constraints", []):
            (op, (a, b)), = c.items()
            if op != "le" or a not in names or b not in names:
                raise DefinitionError(f"{msg['name']}: bad constraint {c}")
            fa = next(f for f in msg["fields"] if f["name"] == a)
            fb = next(f for f in msg["fields"] if f["name"] == b)
            if fa.get("scale", 1) != fb.get("scale", 1):
                raise DefinitionError(f"{msg['name']}: constraint {c} needs equal scales")


def c_float(x: float) -> str:
    s = repr(float(x))
    if "e" not in s and "." not in s:
        s += ".0"
    return s + "f"


def inverse(scale: float) -> float:
    inv = 1.0 / scale
    if abs(inv - round(inv)) < 1e-9 * abs(inv):
        inv = float(round(inv))
    return inv


def field_comment(f: dict) -> str:
    parts = []
    if "scale" in f:
        parts.append(f"raw x {f['scale']:g} = {f.get('unit', '')}".rstrip())
    elif f.get("unit"):
        parts.append(f["unit"])
    if "enum" in f:
        parts.append(f"enum {camel(f['enum'])}")
    if "flags" in f:
        parts.append(f"flags k{camel(f['flags'])}*")
    if "min" in f or "max" in f:
        parts.append(f"valid [{f.get('min', '-')}, {f.get('max', '-')}]")
    if f.get("doc"):
        parts.append(f["doc"])
    return "; ".join(parts)


def render_header(defn: dict) -> str:
    L: list[str] = []
    w = L.append
    w("// GENERATED by protocol/generate.py from protocol/protocol.json -- DO NOT EDIT.")
    w("// Regenerate: python3 protocol/generate.py   (host_tools/tests/test_protocol_generated.py")
    w("// fails when this file and the definition drift apart.)")
    w("#ifndef PROTOCOL_MESSAGES_H")
    w("#define PROTOCOL_MESSAGES_H")
    w("")
    w("#include <stdint.h>")
    w("#include <protocol/wire.h>")
    w("")
    w("namespace proto {")
    w("")
    fr, link, tim = defn["framing"], defn["link"], defn["timing"]
    w(f"static const uint8_t kVersion = {defn['version']};")
    w(f"static const uint8_t kMaxPayload = {fr['max_payload']};")
    w(f"static const uint32_t kBaud = {link['baud']}UL;  // {link['format']}")
    w(f"static const uint32_t kFcpuHz = {tim['f_cpu_hz']}UL;")
    w(f"static const uint32_t kSchedTickUs = {tim['sched_tick_us']}UL;  // task periods are whole ticks")
    cs = defn["current_sense"]
    w(f"// current sense: {cs.get('doc', '')}")
    w(f"static const float kCurrentSenseVoltsPerAmp = {c_float(cs['volts_per_amp'])};")
    w(f"static const uint8_t kCurrentSenseAdcBits = {cs['adc_bits']};")
    w(f"static const float kCurrentSenseAdcVrefV = {c_float(cs['adc_vref_v'])};")
    drv = defn["drive"]
    w("// ---- drive mode defaults at boot (SetDriveLimits changes them) ----")
    w(f"static const float kDriveAccelDefault = {c_float(drv['accel'])};  // m/s^2")
    w(f"static const float kDriveAlphaDefault = {c_float(drv['alpha'])};  // rad/s^2")
    w(f"static const uint32_t kDriveCmdTimeoutDefaultUs = {int(round(drv['cmd_timeout'] * 1e6))}UL;")
    w("")
    w("// ---- task table: periods and cycle budgets ----")
    tasks = tim["tasks"]
    w("enum TaskId : uint8_t {")
    for i, t in enumerate(tasks):
        w(f"    kTask{camel(t['name'])} = {i},  // {t.get('doc', '')}")
    w(f"    kTaskCount = {len(tasks)}")
    w("};")
    for t in tasks:
        w(f"static const uint32_t k{camel(t['name'])}PeriodUs = {t['period_us']}UL;")
        w(f"static const uint32_t k{camel(t['name'])}BudgetCycles = {t['budget_cycles']}UL;")
    w("inline uint32_t task_period_us(uint8_t id) {")
    w("    switch (id) {")
    for t in tasks:
        w(f"        case kTask{camel(t['name'])}: return k{camel(t['name'])}PeriodUs;")
    w("        default: return 0;")
    w("    }")
    w("}")
    w("inline uint32_t task_budget_cycles(uint8_t id) {")
    w("    switch (id) {")
    for t in tasks:
        w(f"        case kTask{camel(t['name'])}: return k{camel(t['name'])}BudgetCycles;")
    w("        default: return 0;")
    w("    }")
    w("}")
    for isr in tim["isr"]:
        w(f"static const uint16_t k{camel(isr['name'])}IsrBudgetCycles = {isr['budget_cycles_per_event']};  // {isr.get('doc', '')}")
    w("")
    w("// ---- enums and flags ----")
    for ename, e in defn["enums"].items():
        w(f"// {e.get('doc', '')}")
        w(f"enum {camel(ename)} : uint8_t {{")
        for k, v in e["values"].items():
            w(f"    k{camel(ename)}{camel(k)} = {v},")
        w("};")
    for fname, fl in defn["flags"].items():
        w(f"// {fl.get('doc', '')}")
        for k, bit in fl["bits"].items():
            w(f"static const uint8_t k{camel(fname)}{camel(k)} = 1u << {bit};")
    w("")
    w("// ---- message types ----")
    w("enum MsgType : uint8_t {")
    for m in defn["messages"]:
        w(f"    kMsg{m['name']} = {m['type']},  // {m['dir']}")
    w("};")
    w("")
    for m in defn["messages"]:
        render_struct(m, w)
    # dispatch helpers
    w("// Payload size of a message type, or -1 for an unknown type.")
    w("inline int16_t payload_size(uint8_t type) {")
    w("    switch (type) {")
    for m in defn["messages"]:
        w(f"        case kMsg{m['name']}: return {payload_size(m)};")
    w("        default: return -1;")
    w("    }")
    w("}")
    w("")
    w("// Table-driven check of a host command: unknown type, bad length, out-of-range field")
    w("// (detail = index of the first offending field, else 255). Changes nothing.")
    w("inline Result validate_command(uint8_t type, const uint8_t* payload, uint8_t len, uint8_t* detail) {")
    w("    *detail = 255;")
    w("    switch (type) {")
    for m in defn["messages"]:
        if m["dir"] != "host_to_robot":
            continue
        w(f"        case kMsg{m['name']}: {{")
        w(f"            {m['name']} msg;")
        w("            if (!msg.decode(payload, len)) return kResultBadLength;")
        w("            return msg.validate(detail);")
        w("        }")
    w("        default: return kResultUnknownType;")
    w("    }")
    w("}")
    w("")
    w("}  // namespace proto")
    w("")
    w("#endif  // PROTOCOL_MESSAGES_H")
    return "\n".join(L) + "\n"


def render_struct(m: dict, w) -> None:
    fields = m["fields"]
    w(f"// {m['name']} ({m['dir']}, type {m['type']}, {payload_size(m)} payload bytes): {m.get('doc', '')}")
    w(f"struct {m['name']} {{")
    w(f"    enum : uint8_t {{ kType = {m['type']}, kSize = {payload_size(m)} }};")
    for f in fields:
        w(f"    {TYPES[f['type']][0]} {f['name']};  // {field_comment(f)}")
    if not fields:
        w("    uint8_t unused_;  // no payload")
    # accessors
    for f in fields:
        if "scale" not in f:
            continue
        scale = f["scale"]
        ctype = TYPES[f["type"]][0]
        if float(scale).is_integer() and scale > 1 and f["type"] == "u16":
            s = int(scale)
            w(f"    uint32_t get_{f['name']}_{f.get('unit', 'units')}() const {{ return static_cast<uint32_t>({f['name']}) * {s}UL; }}")
            w(f"    void set_{f['name']}_{f.get('unit', 'units')}(uint32_t v) {{ {f['name']} = sat_div_u16(v, {s}UL); }}")
        elif f["type"] != "f32":
            w(f"    float get_{f['name']}() const {{ return static_cast<float>({f['name']}) * {c_float(scale)}; }}")
            w("    // Saturates; false when v was NaN (raw 0) or out of the raw range.")
            w(f"    bool set_{f['name']}(float v) {{ return sat_{f['type']}(v, {c_float(inverse(scale))}, &{f['name']}); }}")
        del ctype
    # encode
    w("    void encode(uint8_t* p) const {")
    off = 0
    if not fields:
        w("        (void)p;")
    for f in fields:
        w(f"        put_{f['type']}(p + {off}, {f['name']});")
        off += TYPES[f["type"]][1]
    w("    }")
    w("    // false (and nothing read) when len is not kSize")
    w("    bool decode(const uint8_t* p, uint8_t len) {")
    if not fields:
        w("        (void)p;")
        w("        unused_ = 0;")
    w("        if (len != kSize) return false;")
    off = 0
    for f in fields:
        w(f"        {f['name']} = get_{f['type']}(p + {off});")
        off += TYPES[f["type"]][1]
    w("        return true;")
    w("    }")
    if m["dir"] == "host_to_robot":
        w("    Result validate(uint8_t* detail) const {")
        w("        *detail = 255;")
        for i, f in enumerate(fields):
            lo, hi = raw_bound(f, "min"), raw_bound(f, "max")
            tmin, tmax = TYPES[f["type"]][2], TYPES[f["type"]][3]
            conds = []
            if lo is not None and lo > tmin:
                conds.append(f"{f['name']} < {lo}")
            if hi is not None and hi < tmax:
                conds.append(f"{f['name']} > {hi}")
            if conds:
                w(f"        if ({' || '.join(conds)}) {{ *detail = {i}; return kResultOutOfRange; }}")
        for c in m.get("constraints", []):
            (op, (a, b)), = c.items()
            ia = [f["name"] for f in fields].index(a)
            w(f"        if ({a} > {b}) {{ *detail = {ia}; return kResultOutOfRange; }}  // {a} <= {b}")
        w("        return kResultOk;")
        w("    }")
    w("};")
    w("")


def wire_bytes(defn: dict, msg: dict) -> int:
    fr = defn["framing"]
    body = fr["header_bytes"] + payload_size(msg) + fr["crc_bytes"]
    return body + body // 254 + 1 + 2


def render_tables(defn: dict) -> str:
    L: list[str] = []
    w = L.append
    w("<!-- GENERATED by protocol/generate.py from protocol/protocol.json -- DO NOT EDIT. -->")
    w(f"# Messages of protocol version {defn['version']}")
    w("")
    link = defn["link"]
    byte_rate = link["baud"] / link["bits_per_byte"]
    w(f"Link: {link['baud']} baud {link['format']} = {byte_rate:.0f} bytes/s each way.")
    w("")
    w("| message | type | dir | payload B | wire B | rate | bytes/s | share of link |")
    w("|---|---|---|---|---|---|---|---|")
    total = 0.0
    for m in defn["messages"]:
        wb = wire_bytes(defn, m)
        rate = m.get("rate_hz")
        if rate:
            bps = wb * rate
            total += bps
            w(f"| {m['name']} | {m['type']} | {m['dir']} | {payload_size(m)} | {wb} | {rate} Hz | {bps:.0f} | {100 * bps / byte_rate:.1f} % |")
        else:
            w(f"| {m['name']} | {m['type']} | {m['dir']} | {payload_size(m)} | {wb} | on demand | | |")
    w("")
    w(f"Periodic robot-to-host load: {total:.0f} bytes/s = {100 * total / byte_rate:.1f} % of the UART.")
    w("")
    for m in defn["messages"]:
        w(f"## {m['name']} (type {m['type']}, {m['dir']})")
        w("")
        w(m.get("doc", ""))
        w("")
        if not m["fields"]:
            w("No payload.")
            w("")
            continue
        w("| # | field | type | offset | scale | unit | valid range | csv column | notes |")
        w("|---|---|---|---|---|---|---|---|---|")
        off = 0
        for i, f in enumerate(m["fields"]):
            rng = f"[{f['min']}, {f['max']}]" if "min" in f else ""
            note = f.get("doc", "")
            if "enum" in f:
                note = (note + " enum " + f["enum"]).strip()
            if "flags" in f:
                note = (note + " flags " + f["flags"]).strip()
            w(f"| {i} | {f['name']} | {f['type']} | {off} | {f.get('scale', '')} | {f.get('unit', '')} | {rng} | {f.get('column', f['name'] if m['name'] == 'Telemetry' else '')} | {note} |")
            off += TYPES[f["type"]][1]
        for c in m.get("constraints", []):
            (op, (a, b)), = c.items()
            w("")
            w(f"Constraint: `{a} <= {b}`.")
        w("")
    for ename, e in defn["enums"].items():
        w(f"Enum `{ename}`: " + ", ".join(f"{k} = {v}" for k, v in e["values"].items()) + ".")
        w("")
    for fname, fl in defn["flags"].items():
        w(f"Flags `{fname}`: " + ", ".join(f"bit {b} {k}" for k, b in fl["bits"].items()) + ".")
        w("")
    return "\n".join(L).rstrip() + "\n"


OUTPUTS = ((HEADER, render_header), (TABLES, render_tables))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", action="store_true", help="exit 1 if a generated file is stale")
    args = ap.parse_args(argv)
    try:
        defn = load()
    except (DefinitionError, ValueError, KeyError) as exc:
        print(f"error: {DEFINITION}: {exc}", file=sys.stderr)
        return 2
    stale = []
    for path, render in OUTPUTS:
        text = render(defn)
        old = path.read_text(encoding="utf-8") if path.exists() else None
        if old != text:
            if args.check:
                stale.append(path)
            else:
                path.write_text(text, encoding="utf-8")
                print(f"wrote {path.relative_to(ROOT)}")
    if stale:
        for p in stale:
            print(f"stale: {p.relative_to(ROOT)} differs from {DEFINITION.relative_to(ROOT)}; run python3 protocol/generate.py", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
