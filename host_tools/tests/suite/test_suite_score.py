"""``suite score`` on stored scores that cannot be used: a clear error naming the file
(exit 2), nothing rewritten."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from host_tools.suite import bench, cases

ROOT = Path(__file__).resolve().parents[3]


def _store(tmp_path, name, text):
    d = tmp_path / "reports" / name
    d.mkdir(parents=True)
    (d / "score.json").write_text(text)
    return d / "score.json"


@pytest.mark.parametrize("text, where", [
    ('{"case": "b", "expe', "line 1, character"),           # truncated by a full disk
    ('[1, 2]', "not a score"),                              # another JSON document
    ('{"case": "b"}', "not a score"),                       # keys missing
    ('[' * 100_000 + ']' * 100_000, "nested"),
])
def test_a_corrupt_stored_score_is_named_and_nothing_is_rewritten(tmp_path, text, where):
    label = cases.Case("a", {}, cases.STD, "no_mismatch").label()
    (tmp_path / "labels").mkdir()
    (tmp_path / "labels" / "a.json").write_text(json.dumps(label))
    good = bench.score_case(label, 0, {"verdict": "no_mismatch", "selected": []})
    a = _store(tmp_path, "a", json.dumps(good))
    before = a.read_bytes()
    b = _store(tmp_path, "b", text)
    sel = [cases.Case("a", {}, cases.STD, "no_mismatch"), cases.Case("b", {}, cases.STD, "no_mismatch")]
    with pytest.raises(bench.ScoreFileError) as e:
        bench.collect(str(tmp_path), sel, rescore=True)
    assert str(b) in str(e.value) and where in str(e.value)
    assert a.read_bytes() == before


def test_suite_score_exits_2_on_a_corrupt_score(tmp_path):
    for c in cases.all_cases():
        _store(tmp_path, c.name, '{"case": "x", "expe')
    r = subprocess.run([sys.executable, "-m", "host_tools.suite", "score", "--out", str(tmp_path)],
                       cwd=ROOT, capture_output=True, text=True)
    assert r.returncode == 2, r.stderr
    assert "score.json, line 1, character" in r.stderr and "Traceback" not in r.stderr
