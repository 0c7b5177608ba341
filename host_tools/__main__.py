"""The host tools of the slip-avoiding robot (``ddrobot COMMAND ...`` or
``python -m host_tools COMMAND ...``): record a run from the robot's XBee (log), check the
firmware's timing budgets on a run (timing), find, name and model what a recording shows and
the nominal model leaves out (analyze), record a run from the real firmware in simavr
against the plant (fil), reproduce the thesis's simulations and the analyzer demo (demo),
drive the robot by velocity commands while recording (drive), write a run and its analysis as
an MCAP file for Foxglove (export), make a run from a ROS
bag (import), analyze many run sets on a Dask cluster into a fleet table and drift report
(batch).  ``COMMAND --help`` gives a command's options.  Messages go to stderr; ``-v``
adds details, ``-q`` keeps errors only (both before COMMAND); on a terminal, long work
shows a progress bar.  Exit codes: 0 done, 1 a check
failed, 2 bad input (with the file and the place).
"""
from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys

# command name -> (module, one-line help).  Each module provides add_arguments(parser) and
# main(args) -> int; modules are imported lazily so that one command's optional dependency
# never breaks another command.
COMMANDS = {
    "log": ("host_tools.logger", "record a run from the XBee serial port"),
    "timing": ("host_tools.timing", "check the firmware's timing budgets"),
    "analyze": ("host_tools.analyzer.cli", "find, name and model sim/real mismatch"),
    "fil": ("host_tools.fil", "firmware in the loop: record a run from firmware.elf in simavr"),
    "drive": ("host_tools.robot", "drive the robot (keys or a scripted path), recording as it drives"),
    "demo": ("host_tools.demo", "the main job: thesis reproduction and analyzer demo"),
    "export": ("host_tools.interop.mcap_export", "write a run (and its analysis) as an MCAP file "
               "for Foxglove"),
    "import": ("host_tools.interop.rosbag_import", "make a run folder from a ROS 1 or ROS 2 bag"),
    "batch": ("host_tools.batch.cli", "analyze many run sets on Dask; fleet table and drift report"),
}


def version() -> str:
    """The installed package's version (pyproject.toml), or 'unknown' when not installed."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as _v
    try:
        return _v("ddrobot-host-tools")
    except PackageNotFoundError:
        return "unknown (not installed: pip install -e .)"


def setup_logging(verbosity: int) -> None:
    """Messages to stderr (``host_tools._stdio.StatusHandler``): progress, notes, warnings and
    errors by default, INFO with -v, DEBUG with -vv, errors only with -q (no progress bars
    either).  Idempotent (the handler is replaced, not added twice)."""
    from host_tools import _stdio
    _stdio.install({-1: logging.ERROR, 0: _stdio.STATUS, 1: logging.INFO}.get(verbosity,
                                                                             logging.DEBUG))


def add_verbosity(parser: argparse.ArgumentParser) -> None:
    """-v/-vv and -q (``args.verbose``, ``args.quiet_log``): :func:`setup_logging`'s input."""
    loud = parser.add_mutually_exclusive_group()
    loud.add_argument("-v", "--verbose", action="count", default=0,
                      help="more messages on stderr (-v: progress details, -vv: debugging)")
    loud.add_argument("-q", "--quiet", dest="quiet_log", action="store_true",
                      help="errors only on stderr (no progress bar)")


def build_parser() -> argparse.ArgumentParser:
    prog = "ddrobot" if os.path.basename(sys.argv[0]) == "ddrobot" else "python -m host_tools"
    parser = argparse.ArgumentParser(prog=prog, description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"%(prog)s {version()}",
                        help="print the version and exit")
    add_verbosity(parser)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        p.set_defaults(_module=module)
        try:
            importlib.import_module(module).add_arguments(p)
        except ImportError as exc:  # command not available in this checkout
            p.set_defaults(_import_error=str(exc))
    return parser


def main(argv: list[str] | None = None) -> int:
    from host_tools import _stdio
    try:
        return _main(argv)
    except Exception as exc:
        if not _broken_installation(exc):
            raise
        msg = str(exc)
        if "params.json" in msg or "protocol.json" in msg:
            msg += ("\n(a file of the installation itself is broken: restore it from the "
                    "release or from git)")
        logging.getLogger("host_tools").error("%s", msg)
        return 2
    finally:
        _stdio.settle()  # a closed status pipe never turns into a traceback at exit


def _broken_installation(exc: BaseException) -> bool:
    """An error of the tables every command loads (params/params.json through
    host_tools.params, protocol/protocol.json through host_tools.protocol).  Matched by name:
    a module whose import failed defines a new class each time it is imported again."""
    return (type(exc).__module__, type(exc).__name__) in (
        ("host_tools.params", "TableError"), ("host_tools.protocol", "ProtocolError"))


def _main(argv: list[str] | None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    setup_logging(-1 if args.quiet_log else args.verbose)
    if not getattr(args, "command", None):
        parser.print_help()
        return 2
    if getattr(args, "_import_error", None):
        logging.getLogger("host_tools").error("command '%s' is unavailable: %s", args.command,
                                              args._import_error)
        return 2
    args._owns_process = argv is None  # the command line of this process, not a caller's list
    return int(importlib.import_module(args._module).main(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
