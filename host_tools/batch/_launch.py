"""``python -m host_tools.batch._launch PARENT_PID MEM_MB -- CMD...``: run CMD with an
address-space limit of MEM_MB (0: none), killed when the process PARENT_PID that started it
dies (``PR_SET_PDEATHSIG``, kept across exec).  Used by :mod:`host_tools.batch.task` instead
of a ``preexec_fn``, which is unsafe in a threaded Dask worker."""
from __future__ import annotations

import ctypes
import os
import resource
import signal
import sys

_PR_SET_PDEATHSIG = 1


def main(argv: list[str]) -> int:
    if len(argv) < 4 or argv[2] != "--":
        print("usage: python -m host_tools.batch._launch PARENT_PID MEM_MB -- CMD...",
              file=sys.stderr)
        return 2
    parent, mem_mb, cmd = int(argv[0]), float(argv[1]), argv[3:]
    try:
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
    except (OSError, AttributeError):
        pass
    if os.getppid() != parent:  # the parent died before the prctl: nobody waits for us
        return 1
    if mem_mb > 0:
        lim = int(mem_mb * 2 ** 20)
        resource.setrlimit(resource.RLIMIT_AS, (lim, lim))
    os.execv(cmd[0], cmd)
    return 1  # not reached


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
