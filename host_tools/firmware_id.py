"""The firmware's build identifier (Params.firmware_id, meta.json's logger.firmware_id).

One u32, made by the build (scripts/firmware_id_extra.py, a PlatformIO extra script of the AVR
environments, defines ``FIRMWARE_ID`` for src/) from the checkout's source revision:

    bits 0-27   the commit's short hash: its first 7 hex digits (git's default short hash)
    bit  28     1: a git revision is encoded (so that no revision encodes as 0)
    bits 29-30  0
    bit  31     1: the working tree had changes (``git status --porcelain`` not empty), "-dirty"

A build outside a git checkout (a source archive, no git) defines ``UNKNOWN`` = 0, which is
also what a firmware built without the script reports. :func:`describe` turns the number into
the text the host writes: ``"1a2b3c4"``, ``"1a2b3c4-dirty"``, ``"unknown"``, or for any other
number its 8 hex digits.

This module is imported by the PlatformIO extra script: it uses the standard library only.
"""
from __future__ import annotations

import subprocess
from pathlib import Path

UNKNOWN = 0
_GIT_FLAG = 1 << 28
_DIRTY_FLAG = 1 << 31
_HASH_MASK = (1 << 28) - 1
HASH_DIGITS = 7


def encode(short_hash: str, dirty: bool) -> int:
    """The identifier of a revision: ``short_hash`` (at least 7 hex digits; the first 7 are
    kept) and whether the tree had changes."""
    h = short_hash.strip().lower()
    if len(h) < HASH_DIGITS or any(c not in "0123456789abcdef" for c in h):
        raise ValueError(f"not a git hash: {short_hash!r}")
    return int(h[:HASH_DIGITS], 16) | _GIT_FLAG | (_DIRTY_FLAG if dirty else 0)


def describe(firmware_id: int) -> str:
    """The text of an identifier (see the module's docstring)."""
    v = int(firmware_id) & 0xFFFFFFFF
    if v == UNKNOWN:
        return "unknown"
    if v & _GIT_FLAG and not v & (3 << 29):
        return f"{v & _HASH_MASK:0{HASH_DIGITS}x}" + ("-dirty" if v & _DIRTY_FLAG else "")
    return f"{v:08x}"


def _git(repo: Path, *args: str) -> str | None:
    try:
        r = subprocess.run(["git", "-C", str(repo), *args], capture_output=True, text=True, timeout=30,
                           check=False)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return r.stdout if r.returncode == 0 else None


def revision(repo: str | Path) -> tuple[int, str]:
    """(identifier, text) of the checkout at ``repo``: its HEAD commit and whether the tree has
    changes (tracked or untracked files, .gitignore respected); ``(UNKNOWN, "unknown")`` when
    ``repo`` is not in a git checkout or git is missing."""
    repo = Path(repo)
    head = _git(repo, "rev-parse", "--verify", "--quiet", "HEAD")
    status = _git(repo, "status", "--porcelain") if head else None
    if not head or status is None:
        return UNKNOWN, describe(UNKNOWN)
    fid = encode(head.strip(), dirty=bool(status.strip()))
    return fid, describe(fid)


if __name__ == "__main__":  # python -m host_tools.firmware_id [DIR]: what a build there would carry
    import sys

    fid, text = revision(sys.argv[1] if len(sys.argv) > 1 else Path(__file__).resolve().parent.parent)
    print(f"0x{fid:08x} {text}")
