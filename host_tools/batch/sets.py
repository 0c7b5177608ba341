"""Run sets: what one batch task analyzes (the run folders of one robot on one day).

A run set comes from a folder tree or from a manifest:

* tree ``ROOT/<robot>/<YYYY-MM-DD>/[<set>/]<run>/meta.json``: every folder holding run
  folders (folders with a ``meta.json``) is one run set; its robot is the first folder under
  ROOT, its date the first folder named like ``YYYY-MM-DD`` (none: no date), its name the
  rest of its path.
* manifest ``*.csv`` with the columns ``robot,date,run`` (and optionally ``set``): one row
  per run folder, rows with the same robot, date and set form one run set; or ``*.json``
  ``{"sets": [{"robot", "date", "runs": [...], "set": optional}]}``.  Run paths are relative
  to the manifest's folder (or absolute).

Every problem raises :class:`BadInput` naming the file, the row and the column.
"""
from __future__ import annotations

import csv
import datetime as _dt
import json
import os
import re
from dataclasses import dataclass, field

_DATE = re.compile(r"^\d{4}-\d{2}-\d{2}$")
_SAFE = re.compile(r"[^A-Za-z0-9._-]+")
#: manifest columns (``set`` optional)
MANIFEST_COLUMNS = ("robot", "date", "run")


class BadInput(ValueError):
    """A tree or manifest that cannot be read as run sets (exit 2)."""


@dataclass
class RunSet:
    robot: str                 # "" when not known (e.g. the suite's cases)
    date: str                  # ISO date "YYYY-MM-DD" or ""
    name: str                  # distinguishes several sets of one robot and day
    runs: list[str] = field(default_factory=list)  # absolute run folders

    @property
    def set_id(self) -> str:
        """The set's relative folder under the batch's output: robot/date/name, each part
        reduced to letters, digits, '.', '_' and '-'."""
        parts = [p for p in (self.robot, self.date, self.name) if p]
        return "/".join(_SAFE.sub("_", p).strip(".") or "_" for p in parts) or "_"

    def fingerprint(self) -> list:
        """Size and modification time of each run's files: a re-run redoes a set whose
        recordings changed."""
        out = []
        for r in self.runs:
            for f in ("meta.json", "telemetry.csv", "groundtruth.csv"):
                p = os.path.join(r, f)
                try:
                    st = os.stat(p)
                    out.append([p, st.st_size, st.st_mtime_ns])
                except OSError:
                    out.append([p, None, None])
        return out

    def to_dict(self) -> dict:
        return {"robot": self.robot, "date": self.date, "name": self.name,
                "set_id": self.set_id, "runs": list(self.runs)}


def _check_date(text: str, where: str) -> str:
    text = text.strip()
    if not text:
        return ""
    try:
        if not _DATE.match(text):
            raise ValueError(text)
        return _dt.date.fromisoformat(text).isoformat()
    except ValueError:
        raise BadInput(f"{where}: date {text!r} is not YYYY-MM-DD") from None


def _is_run(path: str) -> bool:
    return os.path.isfile(os.path.join(path, "meta.json"))


def from_tree(root: str) -> list[RunSet]:
    """The run sets of a folder tree (see the module's docstring), sorted by set id."""
    root = os.path.abspath(root)
    if not os.path.isdir(root):
        raise BadInput(f"{root}: not a folder")
    sets = []
    for dirpath, dirnames, _files in os.walk(root):
        dirnames.sort()
        runs = [os.path.join(dirpath, d) for d in dirnames if _is_run(os.path.join(dirpath, d))]
        if _is_run(dirpath):
            dirnames[:] = []  # a run folder's subfolders are not searched
            continue
        if not runs:
            continue
        rel = os.path.relpath(dirpath, root)
        parts = [] if rel == "." else rel.split(os.sep)
        robot = parts[0] if parts else ""
        date_i = next((i for i, p in enumerate(parts) if _DATE.match(p)), None)
        date = _check_date(parts[date_i], dirpath) if date_i is not None else ""
        rest = [p for i, p in enumerate(parts) if i != 0 and i != date_i]
        sets.append(RunSet(robot, date, "/".join(rest), runs))
    if not sets:
        raise BadInput(f"{root}: no run folders (folders with meta.json) under it")
    return _unique(sets, root)


def _unique(sets: list[RunSet], where: str) -> list[RunSet]:
    seen: dict[str, RunSet] = {}
    for s in sets:
        if s.set_id in seen:
            raise BadInput(f"{where}: two run sets map to the output folder {s.set_id!r}")
        seen[s.set_id] = s
    return sorted(sets, key=lambda s: s.set_id)


def from_manifest(path: str) -> list[RunSet]:
    """The run sets of a CSV or JSON manifest (see the module's docstring)."""
    path = os.path.abspath(path)
    base = os.path.dirname(path)
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            text = fh.read()
    except (OSError, UnicodeDecodeError) as exc:
        raise BadInput(f"{path}: cannot be read: {exc}") from None
    groups: dict[tuple[str, str, str], RunSet] = {}

    def add(robot, date, name, run, where):
        run = os.path.normpath(os.path.join(base, run))
        if not _is_run(run):
            raise BadInput(f"{where}: {run} is not a run folder (no meta.json)")
        key = (robot, date, name)
        groups.setdefault(key, RunSet(robot, date, name, [])).runs.append(run)

    if path.endswith(".json"):
        try:
            doc = json.loads(text)
        except json.JSONDecodeError as exc:
            raise BadInput(f"{path}: line {exc.lineno}, column {exc.colno}: {exc.msg}") from None
        entries = doc.get("sets") if isinstance(doc, dict) else None
        if not isinstance(entries, list):
            raise BadInput(f"{path}: expected {{\"sets\": [...]}}")
        for i, e in enumerate(entries):
            where = f"{path}: sets[{i}]"
            if not isinstance(e, dict) or not isinstance(e.get("runs"), list) or not e["runs"]:
                raise BadInput(f"{where}: expected {{\"robot\", \"date\", \"runs\": [...]}}")
            for key in ("robot", "date", "set"):
                if not isinstance(e.get(key, ""), str):
                    raise BadInput(f"{where}, field {key!r}: expected a string")
            date = _check_date(e.get("date", ""), f"{where}, field 'date'")
            for j, r in enumerate(e["runs"]):
                if not isinstance(r, str) or not r:
                    raise BadInput(f"{where}, runs[{j}]: expected a folder path")
                add(e.get("robot", ""), date, e.get("set", ""), r, f"{where}, runs[{j}]")
    else:
        rows = list(csv.reader(text.splitlines()))
        if not rows:
            raise BadInput(f"{path}: empty manifest")
        header = [h.strip() for h in rows[0]]
        missing = [c for c in MANIFEST_COLUMNS if c not in header]
        if missing:
            raise BadInput(f"{path}: row 1 (header): missing column(s) {', '.join(missing)} "
                           f"(expected {','.join(MANIFEST_COLUMNS)}[,set])")
        col = {h: i for i, h in enumerate(header)}
        for n, row in enumerate(rows[1:], start=2):
            if not any(c.strip() for c in row):
                continue
            if len(row) != len(header):
                raise BadInput(f"{path}: row {n}: {len(row)} cells, the header has "
                               f"{len(header)}")
            get = lambda c: row[col[c]].strip() if c in col else ""  # noqa: E731
            date = _check_date(get("date"), f"{path}: row {n}, column {col['date'] + 1} (date)")
            run = get("run")
            if not run:
                raise BadInput(f"{path}: row {n}, column {col['run'] + 1} (run): empty")
            add(get("robot"), date, get("set"), run,
                f"{path}: row {n}, column {col['run'] + 1} (run)")
    if not groups:
        raise BadInput(f"{path}: names no run")
    return _unique(list(groups.values()), path)


def discover(source: str) -> list[RunSet]:
    """A folder is a tree, a file a manifest."""
    return from_tree(source) if os.path.isdir(source) else from_manifest(source)
