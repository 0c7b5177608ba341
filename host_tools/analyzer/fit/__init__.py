"""Stage 4 of the analysis: output-error fitting of vocabulary effects across all runs at once.

A :class:`~.problem.Problem` holds the prepared runs, the replayer and the per-channel noise
floors.  Its residual is the recording minus the simulation of every fit channel of every run,
divided by that channel's noise floor.  Parameters are fitted by
``scipy.optimize.least_squares`` on the simulated trajectories (bounded, after a coarse
multi-start grid, :mod:`.solver`), never on differentiated data.  Each fitted :class:`~.judge.Candidate` is
judged (:mod:`.judge`); the fits run in a pool of worker processes (:mod:`.workers`)."""
