"""FIRMWARE_ID: the build's identifier from the checkout's revision (host_tools/firmware_id.py,
scripts/firmware_id_extra.py), and its text in meta.json. That a real build's Params carry the
checkout's revision is shown by test_upload.py (the uploaded firmware's Params) and
test_fil.py (a recording's meta.json)."""
from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from host_tools import firmware_id as F

ROOT = Path(__file__).resolve().parents[2]


def test_encoding_and_text():
    v = F.encode("1a2b3c4d5e", dirty=False)
    assert v == 0x11A2B3C4 and F.describe(v) == "1a2b3c4"
    assert F.describe(F.encode("1a2b3c4", dirty=True)) == "1a2b3c4-dirty"
    assert F.encode("0000000", False) != F.UNKNOWN  # no revision encodes as "unknown"
    assert F.describe(F.UNKNOWN) == "unknown"
    assert F.describe(0xDEADBEEF) == "deadbeef"  # not this encoding: its hex digits
    with pytest.raises(ValueError):
        F.encode("xyz1234", False)


@pytest.mark.skipif(shutil.which("git") is None, reason="git is not installed")
def test_revision_of_a_checkout_clean_dirty_and_outside(tmp_path):
    repo = tmp_path / "repo"
    repo.mkdir()
    git = ["git", "-C", str(repo), "-c", "user.name=t", "-c", "user.email=t@t"]
    subprocess.run(git + ["init", "-q"], check=True)
    (repo / "a.txt").write_text("1\n")
    subprocess.run(git + ["add", "a.txt"], check=True)
    subprocess.run(git + ["commit", "-q", "-m", "one"], check=True)
    head = subprocess.run(git + ["rev-parse", "HEAD"], capture_output=True, text=True, check=True).stdout.strip()
    assert F.revision(repo) == (F.encode(head, False), head[:7])
    (repo / "a.txt").write_text("2\n")
    assert F.revision(repo)[1] == head[:7] + "-dirty"
    (tmp_path / "plain").mkdir()
    assert F.revision(tmp_path / "plain") == (F.UNKNOWN, "unknown")  # a source archive

