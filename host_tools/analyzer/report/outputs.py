"""The analyzer's output set, all or nothing per invocation.

Every file of one analysis is written into a fresh staging folder that this process creates
exclusively (``tempfile.mkdtemp``: a new name, mode 0700) inside OUT_DIR, so on OUT_DIR's
file system.  Nothing is ever opened for writing at a path of OUT_DIR itself, so a stale
``report.json.tmp`` (or any other name) that is a symbolic link to someone's file is never
followed.  When the set is complete it is committed: under an exclusive lock on OUT_DIR (two
analyses into one folder commit one after the other) and with SIGINT, SIGTERM and SIGHUP held
back (their handler runs after the commit), the previous set's files (report.json's
``outputs`` list) that the new set does not have are removed and each new file is renamed into
place.  A rename replaces the name, never writes through it.  A failure before the commit (a
full disk, a signal while plotting) removes the staging folder and leaves the previous complete
set untouched.  Only a SIGKILL or a power cut during the commit's few renames can leave a mix;
report.json is renamed last, so a report.json always lists the files of its own set."""
from __future__ import annotations

import errno
import fcntl
import json
import os
import shutil
import signal
import stat
import tempfile
from contextlib import contextmanager
from typing import Callable, Iterator

STAGING_PREFIX = ".analyze-staging-"
SERIES_DIR = "series"
# committed last: a report.json present means its set is complete
LAST = "report.json"


def create_staging(out_dir: str) -> str:
    """Create OUT_DIR if missing and a fresh, exclusively created staging folder in it; OSError
    when either cannot be created."""
    os.makedirs(out_dir, exist_ok=True)
    return tempfile.mkdtemp(prefix=f"{STAGING_PREFIX}{os.getpid()}-", dir=out_dir)


def remove_staging(staging: str) -> None:
    shutil.rmtree(staging, ignore_errors=True)


def write_text(staging: str, name: str, text: str) -> None:
    """Write ``name`` (a plain name or ``series/<name>``) as UTF-8 into the staging folder,
    creating it exclusively (O_EXCL | O_NOFOLLOW: never through an existing name).  Characters
    that UTF-8 cannot hold (undecodable bytes of a path) are written as backslash escapes."""
    path = os.path.join(staging, name)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o644)
    with open(fd, "w", encoding="utf-8", errors="backslashreplace", newline="") as fh:
        fh.write(text)
        fh.flush()
        os.fsync(fh.fileno())


@contextmanager
def _signals_held() -> Iterator[None]:
    sigs = {getattr(signal, n) for n in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, n)}
    old = signal.pthread_sigmask(signal.SIG_BLOCK, sigs)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _previous_outputs(out_dir: str) -> list[str]:
    """The files the previous set in OUT_DIR listed (report.json's ``outputs``), each a plain
    name or ``series/<plain name>``; nothing when there is no readable regular report.json."""
    p = os.path.join(out_dir, LAST)
    try:
        if not stat.S_ISREG(os.lstat(p).st_mode):
            return []
        with open(p, encoding="utf-8") as fh:
            names = json.load(fh).get("outputs") or []
    except (OSError, ValueError, AttributeError):
        return []
    return [n for n in names if isinstance(n, str) and _safe_name(n)]


def _safe_name(n: str) -> bool:
    parts = n.split("/")
    return (len(parts) == 1 or (len(parts) == 2 and parts[0] == SERIES_DIR)) and all(
        p and p not in (".", "..") and "\\" not in p and "\0" not in p for p in parts)


def _unlink_if_file(path: str) -> None:
    try:
        if not stat.S_ISDIR(os.lstat(path).st_mode):
            os.unlink(path)
    except FileNotFoundError:
        pass


def commit(staging: str, out_dir: str, names: list[str],
           on_commit: Callable[[], object] | None = None) -> None:
    """Move the staged ``names`` into OUT_DIR as one set (see the module's docstring) and
    remove the staging folder.  ``on_commit()`` is called once the set is in place, before the
    held-back signals are delivered."""
    fd = os.open(out_dir, os.O_RDONLY | os.O_DIRECTORY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        for n in names:     # checked before anything changes: a rename could not replace it
            dest = os.path.join(out_dir, n)
            if os.path.isdir(dest) and not os.path.islink(dest):
                raise IsADirectoryError(errno.EISDIR, "a folder stands where an output goes",
                                        dest)
        with _signals_held():
            new = set(names)
            for old in _previous_outputs(out_dir):
                if old not in new:
                    _unlink_if_file(os.path.join(out_dir, old))
            series = os.path.join(out_dir, SERIES_DIR)
            if any(n.startswith(SERIES_DIR + "/") for n in names):
                try:
                    st = os.lstat(series)
                except FileNotFoundError:
                    st = None
                if st is not None and not stat.S_ISDIR(st.st_mode):
                    os.unlink(series)       # a file or link where the folder goes
                os.makedirs(series, exist_ok=True)
            for n in sorted(names, key=lambda n: n == LAST):
                os.replace(os.path.join(staging, n), os.path.join(out_dir, n))
            try:
                os.rmdir(series)            # an empty series folder left by an older set
            except OSError as exc:
                if exc.errno not in (errno.ENOTEMPTY, errno.EEXIST, errno.ENOENT,
                                     errno.ENOTDIR):
                    raise
            if on_commit is not None:
                on_commit()
            os.fsync(fd)
    finally:
        os.close(fd)            # releases the lock
        remove_staging(staging)
