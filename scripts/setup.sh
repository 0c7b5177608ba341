#!/usr/bin/env bash
# Offline provisioning: installs everything the project needs into git-ignored folders of the
# checkout. Idempotent: a second run checks stamps, downloads nothing and takes a few seconds.
#
#   .venv/         Python environment: PlatformIO Core, host_tools dependencies, pytest
#   .platformio/   PLATFORMIO_CORE_DIR: local stand-in dev-platforms and tool packages
#   .deps/         downloads (.deb files, source packages) and what is unpacked from them
#   .build/host/   the host shared library of lib/* (built by host_tools on demand, too)
#
# Sources: PyPI (Python packages, SCons), Debian (gcc-avr, binutils-avr, avr-libc, simavr, cppcheck,
# avrdude, and Unity 2.5.1 from the ntpsec source package). The PlatformIO registry is never
# contacted: platformio.ini names the official platforms, and this script installs our own
# stand-ins under those names (platforms/), plus tool packages made from the Debian files.
#
# Usage: scripts/setup.sh [--quiet]
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
# shellcheck source=scripts/env.sh
source "$ROOT/scripts/env.sh"

QUIET=0
[[ "${1:-}" == "--quiet" ]] && QUIET=1
say() { [[ $QUIET == 1 ]] || echo "setup: $*"; }
die() { echo "setup: error: $*" >&2; exit 1; }

DEPS="$ROOT/.deps"
STAMPS="$DEPS/stamps"
mkdir -p "$DEPS" "$STAMPS"

# stamp NAME INPUT-STRING: true if step NAME already ran with these inputs.
stamp_ok() { [[ -f "$STAMPS/$1" && "$(cat "$STAMPS/$1")" == "$2" ]]; }
stamp_set() { printf '%s' "$2" > "$STAMPS/$1"; }
hash_of() { cat "$@" | sha256sum | cut -c1-16; }

# ---------------------------------------------------------------------------------------------
# 1. Python environment
# ---------------------------------------------------------------------------------------------
PY_BOOT="${PYTHON:-python3}"
command -v "$PY_BOOT" >/dev/null || die "python3 is required (Debian: apt-get install python3 python3-venv)"
if [[ ! -x "$ROOT/.venv/bin/python" ]]; then
    say "creating .venv"
    "$PY_BOOT" -m venv "$ROOT/.venv" || die "python3 -m venv failed (Debian: apt-get install python3-venv)"
fi
req_hash="$(hash_of "$ROOT/requirements.txt" "$ROOT/pyproject.toml")"
if ! stamp_ok python "$req_hash"; then
    say "installing Python packages from requirements.txt"
    "$ROOT/.venv/bin/python" -m pip install --disable-pip-version-check -q -r "$ROOT/requirements.txt"
    # the host tools themselves, editable: the `ddrobot` command (pyproject.toml)
    say "installing the host tools (pip install -e .)"
    # (the build backend comes from the package index; without it, the .venv's own setuptools)
    pip_log="$(mktemp)"
    "$ROOT/.venv/bin/python" -m pip install --disable-pip-version-check -q --no-deps -e "$ROOT" \
        2>"$pip_log" \
        || "$ROOT/.venv/bin/python" -m pip install --disable-pip-version-check -q --no-deps \
            --no-build-isolation -e "$ROOT" \
        || { cat "$pip_log" >&2; rm -f "$pip_log"; die "pip install -e . failed"; }
    rm -f "$pip_log"
    stamp_set python "$req_hash"
fi
PIO="$ROOT/.venv/bin/pio"
PY="$ROOT/.venv/bin/python"

# ---------------------------------------------------------------------------------------------
# 2. Debian packages: download the pinned .deb files, unpack them (no system install)
# ---------------------------------------------------------------------------------------------
command -v dpkg-deb >/dev/null || die "dpkg-deb is required (a Debian machine)"
APT_UPDATED=0
apt_update_once() {
    if [[ $APT_UPDATED == 0 ]]; then
        say "apt-get update"
        apt-get update -qq >/dev/null || die "apt-get update failed (run as root on Debian bookworm)"
        APT_UPDATED=1
    fi
}

mkdir -p "$DEPS/debs" "$DEPS/unpacked"
deb_list="$ROOT/scripts/deb-packages.txt"
while read -r pkg ver _target; do
    [[ -z "$pkg" || "$pkg" == \#* ]] && continue
    file_ver="${ver//:/%3a}"
    deb="$(ls "$DEPS/debs/${pkg}_${file_ver}_"*.deb 2>/dev/null | head -n1 || true)"
    if [[ -z "$deb" ]]; then
        # apt-get download only knows versions after an update on a fresh machine
        if ! apt-cache show "$pkg=$ver" >/dev/null 2>&1; then apt_update_once; fi
        say "downloading $pkg $ver"
        (cd "$DEPS/debs" && apt-get -o APT::Sandbox::User=root download -qq "$pkg=$ver" >/dev/null) \
            || die "apt-get download $pkg=$ver failed"
        deb="$(ls "$DEPS/debs/${pkg}_${file_ver}_"*.deb | head -n1)"
    fi
    if [[ ! -f "$DEPS/unpacked/$pkg/.done" ]]; then
        rm -rf "$DEPS/unpacked/$pkg"
        dpkg-deb -x "$deb" "$DEPS/unpacked/$pkg"
        touch "$DEPS/unpacked/$pkg/.done"
    fi
done < "$deb_list"

# ---------------------------------------------------------------------------------------------
# 3. Unity 2.5.1 (MIT) from Debian's ntpsec source package, into .deps/unity
# ---------------------------------------------------------------------------------------------
UNITY_DIR="$DEPS/unity"
if [[ ! -f "$UNITY_DIR/unity.c" ]]; then
    src_dir="$DEPS/apt-src"
    mkdir -p "$src_dir/parts" "$src_dir/lists/partial" "$src_dir/download"
    # A deb-src entry derived from the machine's own apt source (deb822 or one-line format).
    : > "$src_dir/parts/src.sources"
    for f in /etc/apt/sources.list.d/*.sources; do
        [[ -f "$f" ]] && sed -E 's/^Types:.*/Types: deb-src/' "$f" >> "$src_dir/parts/src.sources" \
            && echo >> "$src_dir/parts/src.sources"
    done
    if [[ -f /etc/apt/sources.list ]]; then
        grep -E '^deb ' /etc/apt/sources.list | sed -E 's/^deb /deb-src /' > "$src_dir/parts/src.list" || true
    fi
    APT_SRC=(-o "Dir::Etc::SourceList=/dev/null" -o "Dir::Etc::SourceParts=$src_dir/parts"
             -o "Dir::State::Lists=$src_dir/lists" -o "APT::Sandbox::User=root")
    say "fetching the ntpsec source package for Unity"
    apt-get "${APT_SRC[@]}" update -qq >/dev/null || die "apt-get update (deb-src) failed"
    (cd "$src_dir/download" && apt-get "${APT_SRC[@]}" source --download-only -qq ntpsec >/dev/null) \
        || die "apt-get source ntpsec failed"
    orig="$(ls "$src_dir"/download/ntpsec_*.orig.tar.* | head -n1)"
    tmp="$(mktemp -d)"
    tar -xf "$orig" -C "$tmp" --wildcards '*/tests/unity/*'
    rm -rf "$UNITY_DIR" && mkdir -p "$UNITY_DIR"
    cp "$tmp"/ntpsec-*/tests/unity/unity.c "$tmp"/ntpsec-*/tests/unity/unity.h \
       "$tmp"/ntpsec-*/tests/unity/unity_internals.h "$UNITY_DIR/"
    rm -rf "$tmp"
    grep -q "Released under MIT License" "$UNITY_DIR/unity.c" || die "unexpected Unity sources"
fi
# A PlatformIO library manifest for it. -UAVR: Unity 2.5.x puts strings in PROGMEM under
# #ifdef AVR but reads them as RAM, which prints garbage on the ATmega2560.
cat > "$UNITY_DIR/library.json.new" <<'JSON'
{
  "name": "Unity",
  "version": "2.5.1",
  "description": "ThrowTheSwitch Unity 2.5.1, from Debian's ntpsec source package (tests/unity, MIT)",
  "build": {"flags": ["-UAVR"], "extraScript": "unity_extra_script.py"}
}
JSON
cp "$ROOT/scripts/unity_extra_script.py" "$UNITY_DIR/unity_extra_script.py"
if cmp -s "$UNITY_DIR/library.json.new" "$UNITY_DIR/library.json"; then
    rm "$UNITY_DIR/library.json.new"
else
    mv "$UNITY_DIR/library.json.new" "$UNITY_DIR/library.json"
fi

# ---------------------------------------------------------------------------------------------
# 4. PlatformIO tool packages and the local dev-platforms, in PLATFORMIO_CORE_DIR
# ---------------------------------------------------------------------------------------------
# Platforms first: reinstalling a platform makes PlatformIO remove tool packages that no
# installed platform uses at that moment, so the tool packages are (re)installed after it.
plat_hash="$(find "$ROOT/platforms" -type f -print0 | sort -z | xargs -0 cat | sha256sum | cut -c1-16)"
if ! stamp_ok platforms "$plat_hash" || [[ ! -d "$PLATFORMIO_CORE_DIR/platforms/atmelavr" ]]; then
    for plat in native atmelavr; do
        say "installing dev-platform $plat (local stand-in)"
        "$PIO" pkg install -g --skip-dependencies -p "file://$ROOT/platforms/$plat" -f >/dev/null
    done
    stamp_set platforms "$plat_hash"
fi


tools_hash="$(hash_of "$deb_list" "$ROOT/scripts/setup.sh" "$ROOT/scripts/piopkg.py" "$ROOT/requirements.txt")"
tools_missing=0
for name in toolchain-atmelavr tool-simavr tool-avrdude tool-cppcheck tool-scons; do
    [[ -f "$PLATFORMIO_CORE_DIR/packages/$name/.piopm" ]] || tools_missing=1
done
if ! stamp_ok tools "$tools_hash" || [[ $tools_missing == 1 ]]; then
    say "assembling PlatformIO tool packages"
    "$PY" "$ROOT/scripts/piopkg.py" assemble --deps "$DEPS" --deb-list "$deb_list"
    for pkgdir in "$DEPS"/piopkgs/*/; do
        name="$(basename "$pkgdir")"
        say "installing $name"
        "$PIO" pkg install -g --skip-dependencies -f -t "file://$pkgdir" >/dev/null
        "$PY" "$ROOT/scripts/piopkg.py" mark-official --core-dir "$PLATFORMIO_CORE_DIR" --name "$name"
    done
    stamp_set tools "$tools_hash"
fi

# Headless Chromium for the test that loads the analyzer's report.html (only when absent;
# without it that one test is skipped with its reason, nothing else needs it)
if ! command -v chromium >/dev/null && ! command -v chromium-browser >/dev/null; then
    say "installing chromium (Debian) for the report.html test"
    apt-get install -y -qq --no-install-recommends chromium >/dev/null 2>&1 \
        || say "chromium could not be installed (not root, or no package source): the report.html browser test will be skipped"
fi

say "ready (PLATFORMIO_CORE_DIR=$PLATFORMIO_CORE_DIR)"
