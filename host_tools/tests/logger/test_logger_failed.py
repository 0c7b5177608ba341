"""A recording that fails before its experiment runs leaves a folder clearly marked failed
(meta.json "failed" and a FAILED file) that a retry with the same --out replaces; a port that
cannot be opened gives one message, exit 2, and leaves nothing behind."""
from __future__ import annotations

import json

from host_tools import logger as L


def _args(argv):
    import argparse
    p = argparse.ArgumentParser()
    L.add_arguments(p)
    return p.parse_args(argv)


def test_bad_port_one_message_exit_2_nothing_left(tmp_path, capsys):
    out = tmp_path / "run"
    rc = L.main(_args(["--port", "/dev/ddrobot-no-such-port", "--out", str(out), "--quiet",
                       "--experiment", "straight"]))
    err = capsys.readouterr().err
    assert rc == 2
    assert err.count("error:") == 1 and "cannot open port /dev/ddrobot-no-such-port" in err
    assert "Traceback" not in err
    assert not out.exists()


def test_unacknowledged_start_is_marked_failed_and_a_retry_replaces_it(tmp_path, capsys):
    out = tmp_path / "run"
    # loop:// echoes the host's own frames: no Ack ever comes
    argv = ["--port", "loop://", "--out", str(out), "--quiet", "--experiment", "straight",
            "--params-timeout", "0.1"]
    rc = L.main(_args(argv))
    assert rc == 1
    meta = json.loads((out / "meta.json").read_text())
    assert "did not acknowledge Start" in meta["failed"]
    assert "did not acknowledge Start" in (out / "FAILED").read_text()
    capsys.readouterr()
    rc = L.main(_args(argv))  # the same --out: accepted, the failed files replaced
    err = capsys.readouterr().err
    assert rc == 1 and "refusing" not in err
    assert json.loads((out / "meta.json").read_text())["logger"]["end_reason"].startswith("robot did not")


def test_a_recorded_run_is_still_never_overwritten(tmp_path, capsys):
    out = tmp_path / "run"
    out.mkdir()
    (out / "meta.json").write_text(json.dumps({"format": "ddrun/1"}))
    (out / "telemetry.csv").write_text("t_s\n")
    rc = L.main(_args(["--port", "loop://", "--out", str(out), "--quiet"]))
    assert rc == 2 and "refusing to overwrite" in capsys.readouterr().err
    # a FAILED file alone (meta.json not marked) does not make it replaceable
    (out / "FAILED").write_text("x")
    rc = L.main(_args(["--port", "loop://", "--out", str(out), "--quiet"]))
    assert rc == 2 and (out / "telemetry.csv").read_text() == "t_s\n"
