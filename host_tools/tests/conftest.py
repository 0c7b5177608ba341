"""Fixtures shared by the test modules: the firmware and the firmware-in-the-loop simulator.

Session-scoped: built (or found up to date) once per pytest process, not once per module;
each pytest-xdist worker is its own process and builds under fil.pio_build_lock()."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

from host_tools import fil

# The test modules import helpers from one another across the folders (test_badinput takes
# test_runfmt's columns, test_badinput_tools test_logger's arguments): every test folder is on
# sys.path, so a helper module is found by its name whichever test pytest collects first.
for _d in sorted(Path(__file__).resolve().parent.iterdir()):
    if _d.is_dir() and not _d.name.startswith((".", "_")) and str(_d) not in sys.path:
        sys.path.append(str(_d))


@pytest.fixture(scope="session")
def elf():
    try:
        return fil.build_firmware()
    except fil.FilError as exc:
        pytest.skip(f"firmware cannot be built here, so there is nothing to run in the loop: {exc}")


@pytest.fixture(scope="session")
def sim():
    return fil.build_sim()  # failure to build the simulator is a test failure, not a skip
