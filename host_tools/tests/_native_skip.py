"""The skip mark of the tests that need the native libraries (lib/* through the C ABI, and the
truth simulator): a test module skips, with the reason, only when they cannot be built here."""
from __future__ import annotations

import pytest


def needs_native(truth: bool = False) -> pytest.MarkDecorator:
    """``pytestmark = needs_native()``: skip the module when ``host_tools._native`` (and, with
    ``truth``, the truth simulator) cannot be built and loaded."""
    try:
        from host_tools import _native
        _native.effect_vocabulary()
        if truth:
            from host_tools import truth as truth_sim
            truth_sim.build_truth()
        ok, why = True, ""
    except Exception as exc:  # pragma: no cover - the native libraries could not be built here
        ok, why = False, f"native libraries not buildable: {exc}"
    return pytest.mark.skipif(not ok, reason=why)
