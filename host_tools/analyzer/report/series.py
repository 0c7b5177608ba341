"""The per-sample series of an analysis (``series/<run>.csv``, one per run, and the data of
report.html and the PNG plots): per channel the recording, the nominal and updated replays,
their residuals, the noise band, the replay window of each sample (re-anchoring) and whether
the sample lies in a window of significant mismatch.  Columns: :data:`COLUMNS`
(docs/analyzer.md, "Per-sample series")."""
from __future__ import annotations

import csv
import io
import os
from dataclasses import dataclass
from typing import Iterator

import numpy as np

from host_tools.analyzer.locate.episodes import SLIP_UNC
from host_tools.analyzer.report.sections import Analysis

# the analyzer's significance threshold in noise floors (signals.significant_windows' k)
BAND_K = 3.0

COLUMNS = ("channel", "replay", "unit", "t_s", "recording", "nominal", "updated",
           "residual_nominal", "residual_updated", "noise_floor", "replay_uncertainty",
           "band", "replay_window", "in_mismatch_window")


@dataclass(eq=False)
class Series:
    """One channel of one run."""
    run: str
    channel: str
    replay: str                 # "duty" (open loop) or "closed_loop" (lib/control)
    unit: str
    t: np.ndarray
    rec: np.ndarray
    nominal: np.ndarray
    updated: np.ndarray | None
    resid_nominal: np.ndarray
    resid_updated: np.ndarray | None
    floor: float
    unc: np.ndarray             # the replay's own uncertainty per sample (0 when none)
    band: np.ndarray            # BAND_K * sqrt(floor^2 + unc^2): where the residual is noise
    window: np.ndarray          # replay window (re-anchoring) of each sample
    windows: list[tuple[float, float]]  # significant-mismatch windows: [(t_start_s, t_end_s)]

    @property
    def anchor_edges(self) -> list[float]:
        """Times at which a new replay window starts (re-anchored to the recording)."""
        if self.window.size < 2:
            return []
        k = np.flatnonzero(np.diff(self.window) != 0) + 1
        return [float(self.t[i]) for i in k]

    def in_window(self) -> np.ndarray:
        m = np.zeros(self.t.size, bool)
        for a, b in self.windows:
            m |= (self.t >= a) & (self.t <= b)
        return m

    def outside_band(self, updated: bool = False) -> np.ndarray:
        r = self.resid_updated if updated else self.resid_nominal
        return np.abs(r) > self.band if r is not None else np.zeros(self.t.size, bool)

    def worst_floors(self) -> float:
        """Largest RMS over a mismatch window, in noise floors (0 without windows)."""
        best = 0.0
        for a, b in self.windows:
            m = (self.t >= a) & (self.t <= b)
            if m.any() and self.floor > 0:
                best = max(best, float(np.sqrt(np.mean(self.resid_nominal[m] ** 2))) / self.floor)
        return best


def run_series(an: Analysis, i: int) -> list[Series]:
    """Every channel of run ``i``: the open-loop (duty) replay's channels, then the closed-loop
    replay's."""
    out = []
    name = an.preps[i].name
    cl_floor = an.closed_loop.get("noise_floor", {}) if an.closed_loop else {}
    groups = [("duty", an.nominal[i] if i < len(an.nominal) else {},
               an.updated[i] if an.updated is not None else None, an.floors)]
    if i < len(an.cl_nominal) and an.cl_nominal[i]:
        upd = (an.cl_updated[i] if (i < len(an.cl_updated) and
                                    an.closed_loop.get("updated_effects")) else None)
        groups.append(("closed_loop", an.cl_nominal[i], upd, cl_floor))
    for replay, nom, upd, floors in groups:
        for c in sorted(nom):
            ch = nom[c]
            u = upd.get(c) if upd else None
            if u is not None and (u.t.size != ch.t.size):
                u = None
            f = float(floors.get(c) or 0.0)
            unc = (np.asarray(ch.total_unc, float) if ch.total_unc is not None
                   else np.zeros(ch.t.size))
            # a sample that is no evidence (a slip of a windowed replay) has no band: NaN,
            # written empty and left undrawn, never outside it
            unc = np.where(unc >= SLIP_UNC, np.nan, unc)
            seg = (np.asarray(ch.seg, int) if ch.seg is not None
                   else np.zeros(ch.t.size, int))
            out.append(Series(
                run=name, channel=c, replay=replay, unit=ch.unit, t=np.asarray(ch.t, float),
                rec=np.asarray(ch.rec, float), nominal=np.asarray(ch.sim, float),
                updated=None if u is None else np.asarray(u.sim, float),
                resid_nominal=np.asarray(ch.resid, float),
                resid_updated=None if u is None else np.asarray(u.resid, float),
                floor=f, unc=unc, band=BAND_K * np.sqrt(f ** 2 + unc ** 2), window=seg,
                windows=[(w.t_start_s, w.t_end_s) for w in an.windows.get((i, c), [])]))
    return out


def all_series(an: Analysis) -> Iterator[tuple[int, list[Series]]]:
    for i in range(len(an.preps)):
        yield i, run_series(an, i)


def file_name(an: Analysis, i: int) -> str:
    """``series/<run>.csv`` with the run's label made a safe file name."""
    name = an.preps[i].name.replace(os.sep, "_").replace("/", "_") or f"run{i}"
    return f"series/{name}.csv"


def _g(v: float) -> str:
    """10 significant digits (a tenth of the smallest noise floor seen is 1e-5 of a value)."""
    return "" if not np.isfinite(v) else f"{float(v):.10g}"


def to_csv(series: list[Series]) -> str:
    """The run's series as one long-format CSV (one row per channel and sample)."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(COLUMNS)
    for s in series:
        inw = s.in_window()
        for k in range(s.t.size):
            w.writerow([s.channel, s.replay, s.unit, _g(s.t[k]), _g(s.rec[k]), _g(s.nominal[k]),
                        "" if s.updated is None else _g(s.updated[k]),
                        _g(s.resid_nominal[k]),
                        "" if s.resid_updated is None else _g(s.resid_updated[k]),
                        _g(s.floor), _g(s.unc[k]), _g(s.band[k]), int(s.window[k]),
                        int(inw[k])])
    return buf.getvalue()
