"""The one host build recipe (host_tools._build) and the one declaration of each C ABI
(host_tools._cabi): the ctypes signatures are those of the headers, the headers are those of
the definitions and of the exported symbols, stale outputs are rebuilt, and warnings fail."""
from __future__ import annotations

import ctypes
import os
import re
import shutil
import subprocess

import pytest

from host_tools import _build, _cabi, _native, truth

ROOT = _build.ROOT

#: the sources that define each library's C ABI, and the header each one includes
DEFINITIONS = {
    "ddrobot": {"host_tools/native/slipmodel_capi.cpp": "slipmodel_capi.h",
                "host_tools/native/control_capi.cpp": "control_capi.h",
                "host_tools/native/closedloop_capi.cpp": "closedloop_capi.h"},
    "truth": {"sim/truth/truth.cpp": "truth.h"},
}
LOADERS = {"ddrobot": _native.library, "truth": truth._tlib}


def _exported_c_functions(lib_path) -> set[str]:
    nm = shutil.which("nm")
    if nm is None:
        pytest.skip("nm not installed")
    out = subprocess.run([nm, "-D", "--defined-only", str(lib_path)], capture_output=True,
                         text=True, check=True).stdout
    names = set()
    for line in out.splitlines():
        parts = line.split()
        if len(parts) == 3 and parts[1] == "T" and not parts[2].startswith("_"):
            names.add(parts[2])  # C++ names are mangled (_Z...): these are the extern "C" ones
    return names


@pytest.mark.parametrize("library", sorted(DEFINITIONS))
def test_every_exported_c_function_is_declared_once(library):
    path = _build.build(library)
    decl = _cabi.declarations(library)
    assert decl, f"no prototypes parsed from {_cabi.HEADERS[library]}"
    assert _exported_c_functions(path) == set(decl)
    seen: dict[str, str] = {}
    for header in _cabi.HEADERS[library]:
        for name in _cabi.parse_prototypes((ROOT / header).read_text()):
            assert name not in seen, f"{name} declared in {seen.get(name)} and {header}"
            seen[name] = header


@pytest.mark.parametrize("library", sorted(DEFINITIONS))
def test_definitions_match_the_header_prototypes(library):
    """Each defining source includes its header (so the compiler checks it); the definitions'
    argument counts and types are the header's."""
    decl = _cabi.declarations(library)
    defined: dict[str, tuple[str, tuple[str, ...]]] = {}
    for src, header in DEFINITIONS[library].items():
        text = (ROOT / src).read_text()
        assert f'#include "{header}"' in text, f"{src} does not include {header}"
        defs = _cabi.parse_definitions(text)
        assert defs, f"no extern \"C\" definitions found in {src}"
        defined.update(defs)
    assert set(defined) == set(decl)
    for name, (ret, args) in decl.items():
        assert defined[name] == (ret, args), name


@pytest.mark.parametrize("library", sorted(DEFINITIONS))
def test_ctypes_signatures_are_the_headers(library):
    lib = LOADERS[library]()
    for name, (ret, args) in _cabi.declarations(library).items():
        fn = getattr(lib, name)
        assert fn.restype is _cabi.C_TYPES[ret], name
        assert list(fn.argtypes) == [_cabi.C_TYPES[a] for a in args], name


def test_prototype_parser():
    text = '''// comment (int x);
    #ifdef __cplusplus
    extern "C" {
    #endif
    /* block */ void* a_new(void);
    const char* a_name(int i);
    long long a_ticks(void* p);
    int a_run(void* h, int n, const double* t_s,
              double* out, const int32_t* enc);
    #ifdef __cplusplus
    }
    #endif
    '''
    assert _cabi.parse_prototypes(text) == {
        "a_new": ("void*", ()), "a_name": ("char*", ("int",)), "a_ticks": ("long long", ("void*",)),
        "a_run": ("int", ("void*", "int", "double*", "double*", "int32_t*"))}
    with pytest.raises(ValueError, match="not a prototype"):
        _cabi.parse_prototypes("int x = 3;")
    with pytest.raises(ValueError, match="no ctypes mapping"):
        _cabi.ctypes_type("float*")


def test_no_hand_written_ctypes_signatures():
    """argtypes/restype are set in one place, from the headers."""
    pat = re.compile(r"\.(argtypes|restype)\s*=")
    offenders = []
    for folder in ("host_tools", "bench", "sim", "scripts"):
        for py in (ROOT / folder).rglob("*.py"):
            if py.name == "_cabi.py" or "tests" in py.parts:
                continue
            if pat.search(py.read_text()):
                offenders.append(str(py.relative_to(ROOT)))
    assert offenders == []


def test_every_host_target_uses_the_common_flags():
    for t in _build.TARGETS.values():
        if t.simavr and not (_build.simavr_dir() / "include").is_dir():
            continue
        for cmd in t.commands(ROOT / ".build" / "x"):
            assert cmd[0] in (_build.CC, _build.CXX)
            for flag in _build.WARNINGS + ["-O2"]:
                assert flag in cmd, (t.name, flag)
            for inc in _build.lib_roots():
                assert f"-I{inc}" in cmd, (t.name, inc)


def _tmp_target(tmp_path, **kw):
    (tmp_path / "src").mkdir(exist_ok=True)
    (tmp_path / "src" / "k.h").write_text("#define K 7\n")
    (tmp_path / "src" / "main.cpp").write_text(
        '#include "k.h"\n#include <stdio.h>\nint main() { printf("%d\\n", K); return 0; }\n')
    return _build.Target("t", str(tmp_path / "out" / "prog"), (str(tmp_path / "src" / "*.cpp"),),
                         **kw)


def test_a_stale_output_is_rebuilt(tmp_path):
    t = _tmp_target(tmp_path)
    out = _build.build(t)
    assert subprocess.run([str(out)], capture_output=True, text=True).stdout == "7\n"
    built_ns = out.stat().st_mtime_ns
    assert not _build.is_stale(t)
    assert _build.build(t).stat().st_mtime_ns == built_ns  # up to date: kept
    (tmp_path / "src" / "k.h").write_text("#define K 8\n")  # a header, newer than the output
    later = out.stat().st_mtime + 10
    os.utime(tmp_path / "src" / "k.h", (later, later))
    assert _build.is_stale(t)
    assert subprocess.run([str(_build.build(t))], capture_output=True, text=True).stdout == "8\n"
    before = out.stat().st_mtime - 1
    os.utime(tmp_path / "src" / "k.h", (before, before))
    assert not _build.is_stale(t)
    changed = _build.Target(t.name, t.output, t.sources, libs=("-lm", "-lpthread"))
    assert _build.is_stale(changed)  # another command line makes the output stale as well
    _build.build(changed)
    assert not _build.is_stale(changed) and _build.is_stale(t)


def test_a_warning_fails_the_build(tmp_path):
    t = _tmp_target(tmp_path)
    (tmp_path / "src" / "main.cpp").write_text("int main() { int unused = 3; return 0; }\n")
    with pytest.raises(_build.NativeBuildError, match="unused"):
        _build.build(t)
    assert not t.output_path().exists()


def test_a_definition_unlike_its_prototype_does_not_compile(tmp_path):
    (tmp_path / "src").mkdir()
    (tmp_path / "src" / "api.h").write_text('extern "C" { int f_scale(int n); }\n')
    (tmp_path / "src" / "api.cpp").write_text(
        '#include "api.h"\nextern "C" { int f_scale(double n) { return static_cast<int>(n); } }\n')
    t = _build.Target("t", str(tmp_path / "libapi.so"), (str(tmp_path / "src" / "api.cpp"),),
                      shared=True)
    with pytest.raises(_build.NativeBuildError, match="conflicting declaration"):
        _build.build(t)


def test_c_and_cpp_sources_link_into_one_program(tmp_path):
    (tmp_path / "a.c").write_text("int a_twice(int x) { return 2 * x; }\n")
    (tmp_path / "m.cpp").write_text('#include <stdio.h>\nextern "C" int a_twice(int x);\n'
                                    'int main() { printf("%d\\n", a_twice(21)); return 0; }\n')
    t = _build.Target("t", str(tmp_path / "prog"), (str(tmp_path / "a.c"), str(tmp_path / "m.cpp")))
    out = _build.build(t)
    assert subprocess.run([str(out)], capture_output=True, text=True).stdout == "42\n"
    assert list(tmp_path.glob("*.o")) == []


def test_command_line_lists_and_builds(capsys):
    assert _build.main(["--list"]) == 0
    assert "ddrobot" in capsys.readouterr().out
    assert _build.main(["ddrobot"]) == 0
    assert capsys.readouterr().out.strip() == str(_native.library_path())
    with pytest.raises(SystemExit):
        _build.main(["no_such_target"])
    assert ctypes.CDLL(str(_native.library_path())).sm_out_cols() > 0


def test_simavr_targets_get_the_harness_layer():
    """The libsimavr programs get the provisioned libsimavr, sim/common (its avrsim.c linked in),
    the firmware's include/ and avr-libc's device headers searched after the host's."""
    sa = _build.simavr_dir()
    if not (sa / "include").is_dir():
        pytest.skip("libsimavr not provisioned")
    for t in (t for t in _build.TARGETS.values() if t.simavr):
        cmds = t.commands(ROOT / ".build" / "x")
        for cmd in cmds:
            for flag in (f"-I{ROOT / 'sim' / 'common'}", f"-I{ROOT / 'include'}", f"-I{sa / 'include'}"):
                assert flag in cmd, (t.name, flag)
            assert any(cmd[j:j + 2] == ["-idirafter", str(_build.avr_libc_dir())]
                       for j in range(len(cmd))), t.name
        assert "-lsimavr" in cmds[-1]
        assert str(ROOT / "sim" / "common" / "avrsim.c") in " ".join(" ".join(c) for c in cmds)


def test_scripts_build_host_programs_only_through_the_one_recipe():
    """The scripts of sim/ and bench/ build every libsimavr program with
    ``python -m host_tools._build NAME``; none runs a host compiler or links libsimavr itself."""
    host_compiler = re.compile(r"(^|[\s;(|&`])(gcc|g\+\+|cc|c\+\+|clang|clang\+\+)\s", re.M)
    built: set[str] = set()
    for folder in ("sim", "bench"):
        for sh in (ROOT / folder).rglob("*.sh"):
            text = "\n".join(line for line in sh.read_text().splitlines()
                             if not line.lstrip().startswith("#"))
            where = sh.relative_to(ROOT)
            assert not host_compiler.search(text), where
            assert "-lsimavr" not in text and "simavr/sim_avr.h" not in text, where
            for m in re.finditer(r"-m host_tools\._build((?: +[A-Za-z_][\w]*)+)", text):
                built.update(m.group(1).split())
    assert {n for n, t in _build.TARGETS.items() if t.simavr} <= built


def test_a_libsimavr_program_without_the_provisioned_simavr_says_run_setup(tmp_path, monkeypatch):
    monkeypatch.setenv("PLATFORMIO_CORE_DIR", str(tmp_path))
    with pytest.raises(_build.NativeBuildError, match="run scripts/setup.sh"):
        _build.build("isr_bench")
