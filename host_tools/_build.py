"""The one recipe of every host-built binary: shared libraries loaded by ctypes and host programs.

Every host build uses the same compiler and flags (:data:`CXXFLAGS`, :data:`CFLAGS`, both with
``-Werror``) and the same include roots (every ``lib/*/src``, plus a target's own folders). A
target is rebuilt when its output is missing, when any source or any header under its include
roots or source folders is newer than the output, or when its command line changed (kept
beside the output as ``<output>.cmd``). Builds of one target by several processes are
serialised by a file lock; the output is replaced atomically.

Programs that link libsimavr (``simavr=True``) also get the provisioned libsimavr
(``.platformio/packages/tool-simavr``, as ``scripts/env.sh`` names it), the harness layer
``sim/common`` (its ``*.c`` linked in), the firmware's ``include/`` and avr-libc's device
headers after the host's (``-idirafter``).  The scripts of ``sim/`` and ``bench/`` build them
with the command line below.

Command line (prints the path of each output)::

    python -m host_tools._build [--force] TARGET...     # e.g. ddrobot truth bench_plant
    python -m host_tools._build --list
"""
from __future__ import annotations

import argparse
import fcntl
import os
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BUILD_DIR = ROOT / ".build"

CXX = os.environ.get("CXX", "g++")
CC = os.environ.get("CC", "gcc")
WARNINGS = ["-Wall", "-Wextra", "-Werror"]
CXXFLAGS = ["-std=c++14", "-O2"] + WARNINGS
CFLAGS = ["-std=gnu11", "-O2"] + WARNINGS
SHARED_FLAGS = ["-shared", "-fPIC"]
_HEADER_SUFFIXES = (".h", ".hpp")


class NativeBuildError(RuntimeError):
    """A host binary could not be compiled (the message holds the command and its output)."""


def lib_roots() -> list[Path]:
    """The include roots of the libraries: every ``lib/*/src`` (headers as ``<lib/x.h>``)."""
    return sorted(p for p in (ROOT / "lib").glob("*/src") if p.is_dir())


def lib_sources(*names: str) -> tuple[str, ...]:
    """Glob patterns of the C++ sources of the named libraries (all of them when none given)."""
    if not names:
        names = tuple(p.parent.name for p in lib_roots())
    return tuple(f"lib/{n}/src/**/*.cpp" for n in names)


def simavr_dir() -> Path:
    core = Path(os.environ.get("PLATFORMIO_CORE_DIR", ROOT / ".platformio"))
    return core / "packages" / "tool-simavr"


def avr_libc_dir() -> Path:
    """avr-libc's headers in the provisioned avr-gcc (device register names)."""
    return simavr_dir().parent / "toolchain-atmelavr" / "lib" / "avr" / "include"


@dataclass(frozen=True)
class Target:
    """One host binary. ``sources``: glob patterns relative to the repository root (or absolute
    paths); ``includes``: include folders besides ``lib/*/src``; ``output``: path relative to
    the repository root (or absolute)."""
    name: str
    output: str
    sources: tuple[str, ...]
    includes: tuple[str, ...] = ()
    shared: bool = False
    simavr: bool = False
    libs: tuple[str, ...] = field(default=("-lm",))

    def output_path(self) -> Path:
        return _abs(self.output)

    def source_files(self) -> list[Path]:
        pats = list(self.sources)
        if self.simavr:
            pats.append("sim/common/*.c")
        files: list[Path] = []
        for pat in pats:
            hits = sorted(ROOT.glob(pat)) if not Path(pat).is_absolute() else sorted(
                Path("/").glob(pat.lstrip("/")))
            files.extend(h for h in hits if h not in files)
        return files

    def include_dirs(self) -> list[Path]:
        dirs = [_abs(d) for d in self.includes] + lib_roots()
        if self.simavr:
            dirs += [ROOT / "sim" / "common", ROOT / "include"]
        return [d for i, d in enumerate(dirs) if d.is_dir() and d not in dirs[:i]]

    def inputs(self) -> list[Path]:
        """Every file whose change makes the output stale: the sources and the headers in the
        in-tree include folders and in the sources' folders."""
        files = self.source_files()
        folders = {f.parent for f in files} | set(self.include_dirs())
        headers = set()
        for d in folders:
            headers.update(p for p in d.rglob("*") if p.suffix in _HEADER_SUFFIXES)
        return files + sorted(headers)

    def commands(self, out: Path) -> list[list[str]]:
        """The compiler invocations that make ``out``: C sources of a C++ target are compiled
        to objects first; a target without C++ sources is compiled and linked as C."""
        srcs = self.source_files()
        if not srcs:
            raise NativeBuildError(f"{self.name}: no sources match {list(self.sources)}")
        incs = [f"-I{d}" for d in self.include_dirs()]
        link = list(self.libs)
        if self.simavr:
            sa = simavr_dir()
            libdir = sa / "lib" / "x86_64-linux-gnu"
            if not libdir.is_dir():
                libdir = sa / "lib"
            avr_libc = avr_libc_dir()
            incs += [f"-I{sa / 'include'}"]
            if avr_libc.is_dir():  # device register names (<avr/iom2560.h>) after the host's
                incs += ["-idirafter", str(avr_libc)]
            link = [f"-L{libdir}", f"-Wl,-rpath,{libdir}", "-lsimavr"] + link
        kind = SHARED_FLAGS if self.shared else []
        cpp = [s for s in srcs if s.suffix != ".c"]
        c = [s for s in srcs if s.suffix == ".c"]
        if not cpp:
            return [[CC] + CFLAGS + kind + incs + [str(s) for s in c] + ["-o", str(out)] + link]
        cmds, objs = [], []
        for s in c:
            obj = out.with_name(f"{out.name}.{s.stem}.o")
            cmds.append([CC] + CFLAGS + (["-fPIC"] if self.shared else []) + incs
                        + ["-c", str(s), "-o", str(obj)])
            objs.append(str(obj))
        cmds.append([CXX] + CXXFLAGS + kind + incs + [str(s) for s in cpp] + objs
                    + ["-o", str(out)] + link)
        return cmds


def _abs(p: str | Path) -> Path:
    p = Path(p)
    return p if p.is_absolute() else ROOT / p


_HOST = ("host_tools/native",)

#: every host binary of the project, by name
TARGETS: dict[str, Target] = {t.name: t for t in (
    Target("ddrobot", ".build/host/libddrobot.so",
           ("host_tools/native/*.cpp",) + lib_sources(), _HOST, shared=True),
    Target("truth", ".build/truth/libtruth.so",
           ("sim/truth/*.cpp",) + lib_sources("control", "slipmodel"), ("sim/truth",),
           shared=True),
    Target("bench_plant", ".build/bench/bench_plant",
           ("bench/plant/bench_plant.cpp", "host_tools/native/slipmodel_capi.cpp")
           + lib_sources("slipmodel"), _HOST),
    Target("host_check", ".build/bench_control_avr/host_check",
           ("bench/control_avr/host_check.cpp",) + lib_sources("control", "slipmodel")),
    Target("fil", ".build/fil/fil", ("sim/fil/*.cpp",) + lib_sources("slipmodel", "protocol"),
           ("sim/fil",), simavr=True),
    Target("isr_bench", ".build/isr_bench", ("sim/isr_bench/isr_bench.c",), simavr=True),
    Target("fw_smoke", ".build/fw_smoke", ("sim/isr_bench/fw_smoke.cpp",)
           + lib_sources("protocol"), simavr=True),
    Target("sim_selftest", ".build/sim_common/selftest", ("sim/common/selftest/selftest.c",),
           simavr=True),
    Target("control_profile", ".build/bench_control_avr/profile",
           ("bench/control_avr/profile.c",), simavr=True),
    Target("avr_cycles_harness", ".build/bench/avr_cycles_harness",
           ("bench/plant/avr_cycles_harness.c",), simavr=True),
    Target("upload_sim", ".build/upload_sim/upload_sim", ("sim/upload/upload_sim.c",), simavr=True),
)}


def is_stale(target: Target) -> bool:
    out = target.output_path()
    if not out.exists():
        return True
    stamp = out.with_name(out.name + ".cmd")
    try:
        if stamp.read_text() != _stamp(target, out):
            return True
    except OSError:
        return True
    built = out.stat().st_mtime
    return any(f.stat().st_mtime > built for f in target.inputs())


def _stamp(target: Target, out: Path) -> str:
    """The command lines with the output name fixed (the temporary name differs per build)."""
    tmp = _tmp_path(out, 0)
    return "\n".join(" ".join(c) for c in target.commands(tmp)).replace(str(tmp), str(out)) + "\n"


def _tmp_path(out: Path, pid: int) -> Path:
    return out.with_name(f".{out.name}.{pid}.tmp")


def _check_simavr() -> None:
    sa = simavr_dir()
    if not (sa / "include" / "simavr" / "sim_avr.h").is_file() or not (avr_libc_dir() / "avr" / "iom2560.h").is_file():
        raise NativeBuildError(f"libsimavr or avr-libc headers missing under {sa.parent} "
                               "(run scripts/setup.sh)")


def build(target: str | Target, force: bool = False) -> Path:
    """Build ``target`` (a name of :data:`TARGETS` or a :class:`Target`) when missing or stale
    (always, with ``force``) and return the output's path. Raises :class:`NativeBuildError`
    with the compiler's message on failure."""
    t = TARGETS[target] if isinstance(target, str) else target
    if t.simavr:
        _check_simavr()
    out = t.output_path()
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(out.with_name(f".{out.name}.lock"), "w") as lock_file:
        fcntl.flock(lock_file, fcntl.LOCK_EX)
        if not force and not is_stale(t):
            return out
        tmp = _tmp_path(out, os.getpid())
        cmds = t.commands(tmp)
        try:
            for cmd in cmds:
                try:
                    proc = subprocess.run(cmd, capture_output=True, text=True)
                except FileNotFoundError as exc:
                    raise NativeBuildError(
                        f"{cmd[0]} not found: install the system C/C++ compiler") from exc
                if proc.returncode != 0:
                    raise NativeBuildError(
                        f"building {out} failed:\n{' '.join(cmd)}\n{proc.stderr}")
            os.replace(tmp, out)
            out.with_name(out.name + ".cmd").write_text(_stamp(t, out))
        finally:
            tmp.unlink(missing_ok=True)
            for obj in out.parent.glob(f"{tmp.name}.*.o"):
                obj.unlink(missing_ok=True)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m host_tools._build",
                                 description="Build host binaries (prints their paths).")
    ap.add_argument("targets", nargs="*", metavar="TARGET", help=", ".join(TARGETS))
    ap.add_argument("--force", action="store_true", help="rebuild even when up to date")
    ap.add_argument("--list", action="store_true", help="list the targets and their outputs")
    a = ap.parse_args(argv)
    if a.list:
        for t in TARGETS.values():
            print(f"{t.name:12s} {t.output}")
        return 0
    unknown = [n for n in a.targets if n not in TARGETS]
    if unknown or not a.targets:
        ap.error(f"unknown target(s) {unknown}; known: {', '.join(TARGETS)}" if unknown
                 else "name at least one target (--list shows them)")
    for name in a.targets:
        try:
            print(build(name, force=a.force))
        except NativeBuildError as exc:
            print(exc, file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
