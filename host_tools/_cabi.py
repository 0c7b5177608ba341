"""The ctypes signatures of the project's C ABIs, read from their one declaration: the
``extern "C"`` prototypes of one header per library.

========================================  =====================  ============================
header                                    library                functions
========================================  =====================  ============================
``host_tools/native/slipmodel_capi.h``    ``libddrobot.so``      ``sm_*`` (lib/slipmodel)
``host_tools/native/control_capi.h``      ``libddrobot.so``      ``ctl_*`` (lib/control)
``host_tools/native/closedloop_capi.h``   ``libddrobot.so``      ``cl_*`` (lib/closedloop)
``sim/truth/truth.h``                     ``libtruth.so``        ``tr_*`` (truth simulator)
========================================  =====================  ============================

Each ``.cpp`` that defines the functions includes its header, so the compiler checks every
definition against the prototype; :func:`bind` sets ``restype``/``argtypes`` from the same
prototypes, so Python never carries a second copy. The parser understands the small C subset
the headers use (one prototype per declaration, scalar and pointer types of :data:`C_TYPES`).
"""
from __future__ import annotations

import ctypes
import functools
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

HEADERS = {
    "ddrobot": ("host_tools/native/slipmodel_capi.h", "host_tools/native/control_capi.h",
                "host_tools/native/closedloop_capi.h"),
    "truth": ("sim/truth/truth.h",),
}

#: C type (``const`` dropped, pointers as ``T*``) -> ctypes type
C_TYPES = {
    "void": None,
    "int": ctypes.c_int,
    "long long": ctypes.c_longlong,
    "double": ctypes.c_double,
    "int32_t": ctypes.c_int32,
    "char*": ctypes.c_char_p,
    "void*": ctypes.c_void_p,
    "double*": ctypes.POINTER(ctypes.c_double),
    "int*": ctypes.POINTER(ctypes.c_int),
    "int32_t*": ctypes.POINTER(ctypes.c_int32),
}

_PROTO = re.compile(r"^(?P<ret>[A-Za-z_][\w\s\*]*?)\s*\b(?P<name>[A-Za-z_]\w*)\s*\((?P<args>[^()]*)\)$")


def _strip(text: str) -> str:
    text = re.sub(r"/\*.*?\*/", " ", text, flags=re.S)
    text = re.sub(r"//[^\n]*", " ", text)
    return re.sub(r"^\s*#[^\n]*", " ", text, flags=re.M)


def normalise_type(decl: str, has_name: bool = True) -> str:
    """``const double* t_s`` -> ``double*``; ``void* h`` -> ``void*``; ``long long`` stays."""
    s = re.sub(r"\bconst\b", " ", decl).replace("*", " * ")
    words = s.split()
    if has_name and len(words) > 1 and words[-1] != "*":
        words = words[:-1]  # the parameter's name
    base = " ".join(w for w in words if w != "*")
    return base + "*" * words.count("*")


def parse_prototypes(text: str) -> dict[str, tuple[str, tuple[str, ...]]]:
    """Function name -> (return type, argument types) of every prototype in a header's text."""
    body = _strip(text).replace('extern "C"', " ").replace("{", " ").replace("}", " ")
    out: dict[str, tuple[str, tuple[str, ...]]] = {}
    for decl in body.split(";"):
        decl = " ".join(decl.split())
        if not decl:
            continue
        m = _PROTO.match(decl)
        if not m:
            raise ValueError(f"not a prototype the C ABI parser understands: {decl!r}")
        out[m["name"]] = (normalise_type(m["ret"], has_name=False), _arg_types(m["args"]))
    return out


def parse_definitions(text: str) -> dict[str, tuple[str, tuple[str, ...]]]:
    """Function name -> (return type, argument types) of the functions *defined* inside the
    ``extern "C" { ... }`` blocks of a source file's text."""
    out: dict[str, tuple[str, tuple[str, ...]]] = {}
    src = _strip(text)
    for block in re.finditer(r'extern\s+"C"\s*\{', src):
        depth, i, start = 1, block.end(), block.end()
        top = []  # the block's text at brace depth 1 (function bodies left out)
        while depth and i < len(src):
            ch = src[i]
            if ch == "{":
                if depth == 1:
                    top.append(src[start:i])
                depth += 1
            elif ch == "}":
                depth -= 1
                if depth == 1:
                    start = i + 1
            i += 1
        top.append(src[start:i - 1])
        for chunk in top:
            decl = " ".join(chunk.split(";")[-1].split())
            m = _PROTO.match(decl)
            if m:
                out[m["name"]] = (normalise_type(m["ret"], has_name=False), _arg_types(m["args"]))
    return out


def _arg_types(args: str) -> tuple[str, ...]:
    args = " ".join(args.split())
    if args in ("", "void"):
        return ()
    return tuple(normalise_type(a) for a in args.split(","))


@functools.lru_cache(maxsize=None)
def declarations(library: str) -> dict[str, tuple[str, tuple[str, ...]]]:
    """Every prototype of ``library``'s headers (:data:`HEADERS`)."""
    out: dict[str, tuple[str, tuple[str, ...]]] = {}
    for header in HEADERS[library]:
        out.update(parse_prototypes((ROOT / header).read_text()))
    return out


def ctypes_type(c_type: str):
    if c_type not in C_TYPES:
        raise ValueError(f"C type {c_type!r} has no ctypes mapping in host_tools._cabi.C_TYPES")
    return C_TYPES[c_type]


def bind(lib: ctypes.CDLL, library: str) -> ctypes.CDLL:
    """Set ``restype`` and ``argtypes`` of every function ``library``'s headers declare."""
    for name, (ret, args) in declarations(library).items():
        fn = getattr(lib, name)
        fn.restype = ctypes_type(ret)
        fn.argtypes = [ctypes_type(a) for a in args]
    return lib
