#!/usr/bin/env python3
"""Make PlatformIO tool packages from unpacked Debian packages and the SCons wheel.

Called by scripts/setup.sh; not meant to be run by hand.

  piopkg.py assemble --deps .deps --deb-list scripts/deb-packages.txt
      builds .deps/piopkgs/{toolchain-atmelavr,tool-simavr,tool-avrdude,tool-scons}
  piopkg.py mark-official --core-dir .platformio --name tool-scons
      records owner "platformio" in the installed package's .piopm, so that PlatformIO
      treats the local package as the official one and never asks the registry for it.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import stat
import subprocess
import sys
import zipfile
from pathlib import Path

# Package versions follow PlatformIO's convention: major.MMmmpp.build of the upstream tool.
VERSIONS = {
    "toolchain-atmelavr": ("1.50400.0", "avr-gcc 5.4.0, binutils-avr 2.26, avr-libc 2.0.0 (Debian bookworm)"),
    "tool-simavr": ("1.10600.0", "simavr 1.6 with libsimavr (Debian bookworm)"),
    "tool-avrdude": ("1.70100.0", "avrdude 7.1 (Debian bookworm)"),
}

LIB_WRAPPER = """#!/bin/sh
# Runs the unpacked Debian binary with its own shared libraries.
here="$(cd "$(dirname "$0")" && pwd)"
LD_LIBRARY_PATH="$here/../lib/x86_64-linux-gnu${{LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}}"
export LD_LIBRARY_PATH
exec "$here/../libexec/{name}" {extra}"$@"
"""


def read_deb_list(path: Path) -> dict[str, list[str]]:
    groups: dict[str, list[str]] = {}
    for line in path.read_text().splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        pkg, _ver, target = line.split()
        if target != "-":  # "-": unpacked only (.deps/unpacked/<pkg>), no PlatformIO package
            groups.setdefault(target, []).append(pkg)
    return groups


def merge_usr(src: Path, dst: Path) -> None:
    """Copy SRC/usr/* (and SRC/etc, and SRC/lib: a package not yet moved to /usr, such as
    libusb-0.1-4, keeps its libraries in /lib) into DST, without documentation."""
    if (src / "lib").is_dir():
        shutil.copytree(src / "lib", dst / "lib", symlinks=True, dirs_exist_ok=True)
    usr = src / "usr"
    for item in usr.iterdir():
        if item.name == "share":
            for sub in item.iterdir():
                if sub.name in ("doc", "man", "info", "lintian", "bug"):
                    continue
                shutil.copytree(sub, dst / "share" / sub.name, symlinks=True, dirs_exist_ok=True)
            continue
        shutil.copytree(item, dst / item.name, symlinks=True, dirs_exist_ok=True)
    if (src / "etc").is_dir():
        shutil.copytree(src / "etc", dst / "etc", symlinks=True, dirs_exist_ok=True)


def write_manifest(dst: Path, name: str, version: str, description: str) -> None:
    manifest = {"name": name, "version": version, "description": description,
                "system": ["linux_x86_64"]}
    (dst / "package.json").write_text(json.dumps(manifest, indent=2) + "\n")


def wrap_binary(pkg: Path, name: str, extra: str = "") -> None:
    """Move bin/NAME to libexec/NAME and put a wrapper that sets LD_LIBRARY_PATH in bin/."""
    (pkg / "libexec").mkdir(exist_ok=True)
    shutil.move(str(pkg / "bin" / name), str(pkg / "libexec" / name))
    wrapper = pkg / "bin" / name
    wrapper.write_text(LIB_WRAPPER.format(name=name, extra=extra))
    wrapper.chmod(wrapper.stat().st_mode | stat.S_IXUSR | stat.S_IXGRP | stat.S_IXOTH)


def scons_version_from_requirement() -> tuple[str, str]:
    """PlatformIO asks for tool-scons '~4.XYYZZ.0' meaning SCons X.YY.ZZ."""
    from platformio.dependencies import get_core_dependencies  # pylint: disable=import-outside-toplevel

    req = get_core_dependencies()["tool-scons"]
    pio_version = req.lstrip("~^=<> ")
    code = pio_version.split(".")[1]
    major, minor, patch = int(code[0]), int(code[1:3]), int(code[3:5])
    return pio_version, f"{major}.{minor}.{patch}"


def assemble_scons(deps: Path, out: Path) -> None:
    pio_version, scons_version = scons_version_from_requirement()
    wheels = deps / "wheels"
    wheels.mkdir(parents=True, exist_ok=True)
    wheel = next(iter(sorted(wheels.glob(f"[Ss][Cc]ons-{scons_version}-*.whl"))), None)
    if wheel is None:
        subprocess.run([sys.executable, "-m", "pip", "download", "-q", "--disable-pip-version-check",
                        "--no-deps", "--only-binary=:all:", f"scons=={scons_version}", "-d", str(wheels)],
                       check=True)
        wheel = next(iter(sorted(wheels.glob(f"[Ss][Cc]ons-{scons_version}-*.whl"))))
    dst = out / "tool-scons"
    shutil.rmtree(dst, ignore_errors=True)
    dst.mkdir(parents=True)
    with zipfile.ZipFile(wheel) as zf:
        for member in zf.namelist():
            if member.startswith("SCons/"):
                zf.extract(member, dst)
    (dst / "scons.py").write_text(
        "#!/usr/bin/env python3\n"
        "# Launcher for the SCons package unpacked beside this file (PlatformIO runs scons.py).\n"
        "import os\nimport sys\n\n"
        "sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))\n"
        "import SCons.Script  # noqa: E402\n\n"
        "SCons.Script.main()\n")
    write_manifest(dst, "tool-scons", pio_version, f"SCons {scons_version} from its PyPI wheel")


def assemble(deps: Path, deb_list: Path) -> None:
    out = deps / "piopkgs"
    out.mkdir(parents=True, exist_ok=True)
    for target, pkgs in read_deb_list(deb_list).items():
        dst = out / target
        shutil.rmtree(dst, ignore_errors=True)
        dst.mkdir(parents=True)
        for pkg in pkgs:
            merge_usr(deps / "unpacked" / pkg, dst)
        version, description = VERSIONS[target]
        write_manifest(dst, target, version, description)
        if target == "tool-simavr":
            wrap_binary(dst, "simavr")
        elif target == "tool-avrdude":
            wrap_binary(dst, "avrdude", extra='-C "$here/../etc/avrdude.conf" ')
    assemble_scons(deps, out)


def mark_official(core_dir: Path, name: str) -> None:
    meta_path = core_dir / "packages" / name / ".piopm"
    if not meta_path.is_file():
        sys.exit(f"piopkg: {meta_path} is missing: did 'pio pkg install' fail?")
    meta = json.loads(meta_path.read_text())
    meta.setdefault("spec", {})["owner"] = "platformio"
    meta_path.write_text(json.dumps(meta))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="cmd", required=True)
    a = sub.add_parser("assemble")
    a.add_argument("--deps", type=Path, required=True)
    a.add_argument("--deb-list", type=Path, required=True)
    m = sub.add_parser("mark-official")
    m.add_argument("--core-dir", type=Path, required=True)
    m.add_argument("--name", required=True)
    args = parser.parse_args()
    if args.cmd == "assemble":
        assemble(args.deps, args.deb_list)
    else:
        mark_official(args.core_dir, args.name)
    return 0


if __name__ == "__main__":
    os.umask(0o022)
    sys.exit(main())
