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


def _result(i: int, expect: str, ok: bool, length: str, analysis_s: float) -> dict:
    named = ok and expect == "explained"
    return {"case": f"c{i}", "expect": expect, "ok": ok, "rc": 0, "length": length,
            "verdict": expect if ok else "unexplained", "selected": ["payload"] if named else [],
            "named": ["payload"] if named else [], "true": "payload" if expect == "explained" else "",
            "named_all": named, "named_any": named, "analysis_s": analysis_s, "peak_rss_mb": 300.0,
            "param": {"effect": "payload", "name": "mass_kg", "true": 0.4, "fitted": 0.41 if named else None,
                      "how": "selected", "rel_err_deviation": 0.02 if named else None,
                      "rel_err_value": 0.02 if named else None}}


def _row(text: str, figure: str) -> str:
    return next(line for line in text.splitlines() if line.startswith(figure))


def test_the_summary_judges_each_figure_against_the_analyzer_issue_targets():
    """12 of 13 effects named is 92 %: short of the 95 % target (an older target, 90 %, called it
    met); 12 of 13 parameters meet their 90 %; a 20 s run analysed in 35 s misses its 30 s, a 1 min
    run in 35 s meets its 60 s."""
    results = ([_result(i, "explained", i != 0, "short", 5.0) for i in range(13)]
               + [_result(13, "no_mismatch", True, "20 s", 35.0),
                  _result(14, "no_mismatch", True, "1 min", 35.0)])
    text, m = bench.summarize(results, 100.0)
    assert m["named"] == pytest.approx(12 / 13)
    assert ">= 95 %" in _row(text, "effect cases naming every true effect")
    assert _row(text, "effect cases naming every true effect").endswith("MISSED")
    assert ">= 90 %" in _row(text, "main parameter within 25 % (deviation")
    assert _row(text, "main parameter within 25 % (deviation").endswith("met")   # 12/13 ≥ 90 %
    assert "<= 30" in _row(text, "20 s runs: slowest analysis") and \
        _row(text, "20 s runs: slowest analysis").endswith("MISSED")
    assert "<= 60" in _row(text, "1 min runs: slowest analysis") and \
        _row(text, "1 min runs: slowest analysis").endswith("met")
    assert _row(text, "nulls giving no_mismatch").endswith("met")
