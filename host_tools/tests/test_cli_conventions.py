"""Conventions of the command line (issue 25 item 5): ``--version``; ``logging`` with -v/-q
at the entry point; a description on every command and help on every option; values shown to
people in words, not as Python reprs."""
from __future__ import annotations

import argparse
import logging
import re

import pytest

from host_tools import humanize
from host_tools.__main__ import build_parser, main, setup_logging


def _walk(p: argparse.ArgumentParser, path: list[str]):
    yield path, p
    for a in p._actions:
        if isinstance(a, argparse._SubParsersAction):
            for name, sp in a.choices.items():
                yield from _walk(sp, path + [name])


def test_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert re.search(r"\d+\.\d+\.\d+", capsys.readouterr().out)


def test_every_command_and_option_has_help():
    missing = []
    for path, p in _walk(build_parser(), ["ddrobot"]):
        if not p.description:
            missing.append(" ".join(path) + ": no description")
        for a in p._actions:
            if isinstance(a, argparse._SubParsersAction) or a.dest == "help":
                continue
            if not a.help or a.help == argparse.SUPPRESS:
                missing.append(f"{' '.join(path)} {'/'.join(a.option_strings) or a.dest}: no help")
    assert not missing, missing


def test_fil_record_help_describes_the_command(capsys):
    with pytest.raises(SystemExit):
        main(["fil", "record", "--help"])
    out = capsys.readouterr().out
    assert "simavr" in out and "--live" in out and "acceleration phase" in out


@pytest.mark.parametrize("flags, shown", [([], {"warning", "error"}),
                                          (["-v"], {"info", "warning", "error"}),
                                          (["-vv"], {"debug", "info", "warning", "error"}),
                                          (["-q"], {"error"})])
def test_verbosity_flags(flags, shown, capsys):
    args = build_parser().parse_args(flags + ["export", "r", "--out", "x.mcap"])
    setup_logging(-1 if args.quiet_log else args.verbose)
    log = logging.getLogger("host_tools.interop.test")
    for level in ("debug", "info", "warning", "error"):
        getattr(log, level)("message at %s", level)
    err = capsys.readouterr().err
    assert {lv for lv in ("debug", "info", "warning", "error") if f"{lv}: message at {lv}" in err} == shown
    setup_logging(0)
    assert len([h for h in logging.getLogger("host_tools").handlers if getattr(h, "_ddrobot", False)]) == 1


def test_values_for_people_are_words_not_reprs():
    sel = [{"effect": "motor_back_emf", "params": {"ke_ratio": 1.06012}, "equivalent": []},
           {"effect": "axle_viscous", "params": {"c": 2.5e-4}, "equivalent": ["motor_back_emf"]}]
    text = humanize.selected(sel)
    assert text == ("motor_back_emf (ke_ratio = 1.06); axle_viscous (c = 0.00025), equivalent "
                    "on these data: motor_back_emf")
    score = humanize.param_score({"effect": "motor_back_emf", "name": "ke_ratio", "true": 1.2,
                                  "fitted": 1.19989, "rel_err_value": 9.433962264149903e-05})
    assert score == "ke_ratio of motor_back_emf: fitted 1.2, true 1.2 (error 0.0094 %)"
    for t in (text, score, humanize.effects({"payload": {"mass_kg": 0.5}})):
        assert not re.search(r"[\[\]{}']", t), t
    assert humanize.selected([]) == "nothing"


def test_demo_index_has_no_reprs(tmp_path):
    import json

    from host_tools import demo
    (tmp_path / "analyzer").mkdir()
    (tmp_path / "analyzer" / "summary.json").write_text(json.dumps({
        "case": {"effects": {"motor_back_emf": {"ke_ratio": 1.2}}},
        "score": {"verdict": "explained", "selected": ["motor_back_emf"], "named": ["motor_back_emf"],
                  "param": {"effect": "motor_back_emf", "name": "ke_ratio", "true": 1.2,
                            "fitted": 1.19, "rel_err_value": 0.0083}}}))
    demo._index(str(tmp_path), 1.0)
    text = (tmp_path / "README.md").read_text()
    line = next(x for x in text.splitlines() if "Hidden truth" in x)
    assert "motor_back_emf (ke_ratio = 1.2)" in line and "error 0.83 %" in line
    assert not re.search(r"[\[\]{}]|'\w+':", line.replace("](", "")), line


def test_fit_plot_title_in_words_and_legend_beside_the_bars(tmp_path, monkeypatch):
    from host_tools import demo
    plt = demo._plt()
    figs = []
    monkeypatch.setattr(plt, "close", lambda fig=None: figs.append(fig))
    rep = {"verdict": "explained",
           "selected": [{"effect": "motor_back_emf", "params": {"ke_ratio": 1.0601},
                         "equivalent": []}],
           "fit": {"noise_floor": {"omega_r": 0.1, "x_m": 0.01},
                   "rmse_before": {"omega_r": 3.0, "x_m": 0.05},
                   "rmse_after": {"omega_r": 0.1, "x_m": 0.01}}}
    demo._fit_plot(rep, str(tmp_path / "fit.png"))
    ax = figs[0].axes[0]
    assert ax.get_title() == "verdict explained: selected motor_back_emf (ke_ratio = 1.06)"
    figs[0].canvas.draw()
    r = figs[0].canvas.get_renderer()
    assert ax.get_legend().get_window_extent(r).x0 >= ax.get_window_extent(r).x1
    monkeypatch.undo()
    plt.close(figs[0])
