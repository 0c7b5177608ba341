"""Stage 3 of the analysis: noise floors from the data, the windows where each nominal replay's
residual stands out of them, and whether the recordings disagree with the nominal model at all.

:func:`~.mismatch.locate_mismatch` takes the floors (:mod:`.floors`), marks the slips the
model's tolerance does not pin down as no evidence (:mod:`.episodes`) and finds the windows;
:func:`~.mismatch.detect_mismatch` decides, with the test for a consistent bias and the wheel
pairs' difference (:mod:`.bias`), the wheels' torque imbalance (:mod:`.wheels`) and each
wheel's once-per-revolution term (:mod:`.revolution`)."""
