"""Fixtures shared by the test modules: the firmware and the firmware-in-the-loop simulator."""
from __future__ import annotations

import pytest

from host_tools import fil


@pytest.fixture(scope="module")
def elf():
    try:
        return fil.build_firmware()
    except fil.FilError as exc:
        pytest.skip(f"firmware cannot be built here, so there is nothing to run in the loop: {exc}")


@pytest.fixture(scope="module")
def sim():
    return fil.build_sim()  # failure to build the simulator is a test failure, not a skip
