"""Fixtures shared by the test modules: the firmware and the firmware-in-the-loop simulator.

Session-scoped: built (or found up to date) once per pytest process, not once per module;
each pytest-xdist worker is its own process and builds under fil.pio_build_lock()."""
from __future__ import annotations

import pytest

from host_tools import fil


@pytest.fixture(scope="session")
def elf():
    try:
        return fil.build_firmware()
    except fil.FilError as exc:
        pytest.skip(f"firmware cannot be built here, so there is nothing to run in the loop: {exc}")


@pytest.fixture(scope="session")
def sim():
    return fil.build_sim()  # failure to build the simulator is a test failure, not a skip
