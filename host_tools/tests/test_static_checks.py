"""The static checks of scripts/test.sh cannot pass by finding nothing: the provisioned
cppcheck (tool-cppcheck, made by scripts/setup.sh from Debian's package) loads its library
configurations and reports planted defects, and the project's ruff configuration reports a
planted bug."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
CORE_DIR = Path(os.environ.get("PLATFORMIO_CORE_DIR", ROOT / ".platformio"))
CPPCHECK = CORE_DIR / "packages" / "tool-cppcheck" / "cppcheck"

PLANTED_CPP = """\
#include <string.h>
int past_the_end() { int a[2] = {0, 0}; return a[2]; }
void overflow(char* out) { char buf[4]; strcpy(buf, "too long"); strcpy(out, buf); }
"""


@pytest.mark.skipif(not CPPCHECK.exists(), reason="tool-cppcheck not provisioned (scripts/setup.sh)")
def test_provisioned_cppcheck_reports_planted_defects(tmp_path):
    src = tmp_path / "planted.cpp"
    src.write_text(PLANTED_CPP)
    res = subprocess.run([str(CPPCHECK), "--enable=warning,style", "--error-exitcode=3",
                          "--template={id}", "--quiet", str(src)],
                         capture_output=True, text=True, timeout=120)
    out = res.stdout + res.stderr
    assert "std.cfg" not in out, out  # "Failed to load std.cfg": the data folder is misplaced
    assert res.returncode == 3, out
    assert "arrayIndexOutOfBounds" in out
    # known only from std.cfg (strcpy's buffer size rule)
    assert "bufferAccessOutOfBounds" in out


def test_ruff_configuration_reports_a_planted_bug(tmp_path):
    ruff = Path(sys.executable).with_name("ruff")
    if not ruff.exists():
        pytest.skip("ruff not installed (requirements.txt)")
    bad = tmp_path / "planted.py"
    bad.write_text("import os\n\n\ndef f(x=[]):\n    return undefined_name + x\n")
    res = subprocess.run([str(ruff), "check", "--no-cache", "--config", str(ROOT / "pyproject.toml"),
                          "--output-format", "concise", str(bad)],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 1, res.stdout + res.stderr
    for code in ("F401", "F821", "B006"):
        assert code in res.stdout, res.stdout
