"""The host tools' command line: `--help` describes the tools, and the set-up installs the
`ddrobot` console command (pyproject.toml) beside `python -m host_tools`."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from host_tools.__main__ import COMMANDS, main


def test_help_describes_every_tool(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for name in COMMANDS:
        assert f"({name})" in out and name in out
    assert "Exit codes" in out


def test_no_command_is_bad_input(capsys):
    assert main([]) == 2


def test_console_command_is_installed():
    exe = Path(sys.executable).parent / "ddrobot"
    assert exe.exists(), "the ddrobot command is missing: run scripts/setup.sh (pip install -e .)"
    res = subprocess.run([str(exe), "--help"], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0 and res.stdout.startswith("usage: ddrobot")
    assert "analyze" in res.stdout
