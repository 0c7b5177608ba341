"""The walk of ``analyze``'s call path through the analyzer's files:
``python bench/analyzer/walk_call_path.py RUN_DIR [RUN_DIR ...]``.

Runs :func:`host_tools.analyzer.pipeline.analyze` on the run folders (one analysis, nothing
written, its messages below warnings silenced) under ``sys.setprofile`` and keeps, in call
order, every call of a function defined in the analyzer package (``host_tools/analyzer``;
comprehensions and lambdas belong to the function they are in) down to ``--depth`` such calls
below ``analyze`` (0: all; the pipeline module's own functions that ``analyze`` calls, such as
``front``, count as ``analyze``'s level, so the stages are its depth-1 calls).  Consecutive
calls within one file are a *stay*; a stay in a file an earlier stay already visited is a
*return*.  Prints the number of stays, files and returns, each file's visits (stays) and calls
in the order of its first visit, and the sequence of stays.  A reader who follows the code from
``analyze`` reads the stage files in order when the returns are few.

Only the main process is seen: with ``--jobs`` 2 or more the candidates' fits run in worker
processes (as ``ddrobot analyze`` runs them), with ``--jobs 1`` in this one.  Figures, not a
timed test: the counts do not depend on the machine's speed."""
from __future__ import annotations

import argparse
import json
import logging
import os
import sys
from collections import Counter
from dataclasses import dataclass, field
from types import FrameType
from typing import Any, Sequence

ROOT = os.path.abspath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)


_CHILD_UNPROFILED: list[bool] = []


@dataclass
class Walk:
    """The stays of one walk: (file relative to the analyzer package, calls) in order."""
    stays: list[tuple[str, int]] = field(default_factory=list)

    @property
    def files(self) -> list[str]:
        """The files in the order of their first visit."""
        return list(dict.fromkeys(f for f, _ in self.stays))

    @property
    def visits(self) -> Counter[str]:
        return Counter(f for f, _ in self.stays)

    @property
    def calls(self) -> Counter[str]:
        c: Counter[str] = Counter()
        for f, n in self.stays:
            c[f] += n
        return c

    @property
    def returns(self) -> int:
        return len(self.stays) - len(self.files)

    def summary(self) -> dict[str, Any]:
        return {"stays": len(self.stays), "files": len(self.files), "returns": self.returns,
                "visits": {f: self.visits[f] for f in self.files},
                "calls": {f: self.calls[f] for f in self.files},
                "sequence": [list(s) for s in self.stays]}


def walk(run_dirs: Sequence[str], depth: int = 2, jobs: int = 2,
         ignore: Sequence[str] = ()) -> Walk:
    """Analyze ``run_dirs`` under the profiler and return the walk (see the module's text);
    the files in ``ignore`` (relative to the package, e.g. ``signals.py``) are walked as if
    they were outside it."""
    import host_tools.analyzer as pkg
    from host_tools.analyzer.pipeline import analyze

    base = os.path.dirname(os.path.abspath(pkg.__file__ or "")) + os.sep
    skip = {os.path.normpath(f) for f in ignore}
    counted: list[bool] = []     # per open Python frame: whether it opened an analyzer level
    level = [0]                  # open analyzer levels (analyze's own included)
    pipeline = os.path.join(base, "pipeline.py")
    calls: list[str] = []

    def profile(frame: FrameType, event: str, arg: Any) -> None:
        if event == "call":
            code = frame.f_code
            mine = (code.co_filename.startswith(base) and not code.co_name.startswith("<")
                    and os.path.relpath(code.co_filename, base) not in skip)
            if mine and (depth <= 0 or level[0] <= depth):
                calls.append(os.path.relpath(code.co_filename, base))
            # the pipeline's own functions below analyze (front, _load_runs) are analyze's level
            opens = mine and not (level[0] == 1 and code.co_filename == pipeline)
            if opens:
                level[0] += 1
            counted.append(opens)
        elif event == "return" and counted:
            if counted.pop():
                level[0] -= 1

    quiet = lambda msg: None  # noqa: E731
    if not _CHILD_UNPROFILED:
        # a forked fitting worker is not walked: it starts without the profiler
        os.register_at_fork(after_in_child=lambda: sys.setprofile(None))
        _CHILD_UNPROFILED.append(True)
    log_level = pkg.log.level
    pkg.log.setLevel(logging.WARNING)  # the fits' progress lines too (the package's logger)
    sys.setprofile(profile)
    try:
        analyze(list(run_dirs), jobs=jobs, log=quiet)
    finally:
        sys.setprofile(None)
        pkg.log.setLevel(log_level)
    out = Walk()
    for f in calls:
        if out.stays and out.stays[-1][0] == f:
            out.stays[-1] = (f, out.stays[-1][1] + 1)
        else:
            out.stays.append((f, 1))
    return out


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="bench/analyzer/walk_call_path.py", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+", help="run folders (one analysis)")
    ap.add_argument("--depth", type=int, default=2,
                    help="analyzer calls below analyze that are walked (0: all; default 2)")
    ap.add_argument("--jobs", type=int, default=2, help="fitting processes (default 2)")
    ap.add_argument("--ignore", action="append", default=[], metavar="FILE",
                    help="a file of the package walked as if outside it (shared helpers such "
                         "as signals.py); repeatable")
    ap.add_argument("--json", action="store_true", help="print the figures as JSON")
    args = ap.parse_args(argv)
    from host_tools._stdio import out
    w = walk(args.runs, args.depth, args.jobs, args.ignore)
    s = w.summary()
    if args.json:
        out(json.dumps(s, indent=1))
        return 0
    ignored = f", ignoring {', '.join(args.ignore)}" if args.ignore else ""
    out(f"analyze on {len(args.runs)} run(s), depth {args.depth or 'all'}, jobs {args.jobs}"
          f"{ignored}: {s['stays']} stays in {s['files']} files, {s['returns']} returns")
    out(f"{'file':34s} {'visits':>6s} {'calls':>7s}")
    for f in w.files:
        out(f"{f:34s} {w.visits[f]:6d} {w.calls[f]:7d}")
    out("sequence: " + " > ".join(f"{f}({n})" for f, n in w.stays))
    return 0


if __name__ == "__main__":
    from host_tools._stdio import settle
    rc = main()
    settle()  # a closed pipe (| head) never turns the figures into a traceback
    sys.exit(rc)
