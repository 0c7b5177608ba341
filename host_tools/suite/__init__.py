"""The concealed-effect suite: cases made by the independent truth simulator
(``sim/truth`` via ``host_tools.truth``), hidden labels kept apart from the run folders, and a
benchmark that runs the analyzer on every case and scores it. See docs/suite.md.

``python -m host_tools.suite list | generate | bench [--fast]``."""
