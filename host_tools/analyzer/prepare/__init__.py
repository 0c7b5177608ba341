"""Stage 1 of the analysis: a recorded run made ready for replay, from the recording alone
(no model enters): when each recorded input took effect (:mod:`.timing`), the run typed and cut
into replay windows (:mod:`.run`), its inputs reconstructed (:mod:`.inputs`) and how its
recorder computes odometry (:mod:`.odometry`)."""
