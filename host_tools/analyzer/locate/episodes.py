"""The nominal replay's slip episodes that the model's tolerance does not pin down, marked as no
evidence in the replay uncertainty of the runs and of their nominal channels."""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from host_tools.analyzer.prepare.run import PreparedRun
from host_tools.analyzer.replay.channels import FIT_CHANNELS, Channel


# Where the nominal model cannot pin the replay down, the replay is no evidence.  A run replayed
# in windows notes its nominal replay's slip episodes (``replay.anchors``).  In a slip the body's
# motion and the slipping wheels follow the contact forces, whose size and direction follow the
# slip velocity and the contact's form, which no plant reproduces in detail: the tolerance
# ensemble can call a slip pinned and the recording still depart (a braking reversal of the
# MuJoCo tuning set's 60 s null: 6 camera floors of slip distance where the 8 draws spread by
# 0.4, and 4-6 floors of current in a slipping reversal where they spread by 0.5).  So:
# - the pose channels are no evidence from a slip's onset until the replay is re-anchored (the
#   end of its window; a window is cut after each slip, ``anchors._edges_after_slip``): the pose
#   integrates the slip's error;
# - the wheel-speed and current channels are no evidence within a slip episode, and when the
#   episode is unpinned — inside it the replay's own uncertainty of a pose channel (the tolerance
#   ensemble and the input spread, ``Channel.unc``) exceeds that channel's noise floor: the model
#   cannot say where the body goes (a 3 s spin at the start of heldback6's MuJoCo 60 s null ended
#   2.5 rad off, the ensemble spreading by 0.28 rad) — until BURN_IN_S after it ends, while the
#   wheels settle from the body's unpinned motion.  Elsewhere they are evidence, the ensemble's
#   spread joining the noise floor as everywhere.
# "No evidence" is an unbounded replay uncertainty (UNPINNED_UNC): the deflated residual is nil
# there, in the decisions and the fits alike.  A run replayed in one window (up to 6 s, from
# rest) notes no episodes: its slips are the experiment's regime, its replay starts pinned at
# rest, and the friction effects show there.
POSE_CHANNELS = ("x_m", "y_m", "phi_rad")
UNPINNED_UNC = 1e9
SLIP_UNC = 1e8      # a wheel channel in a pinned slip: no evidence, its pair's difference is


@dataclass(frozen=True)
class Unpinned:
    """What :func:`unpinned_episodes` returns, per run."""
    preps: list[PreparedRun]               # with that replay uncertainty (``replay_unc``)
    nominal: list[dict[str, Channel]]      # the nominal channels with it (``unc``)
    episodes: list[list[tuple[float, float]]]  # (onset, end) of the unpinned episodes


def unpinned_episodes(preps: Sequence[PreparedRun], nominal: Sequence[Mapping[str, Channel]],
                      floors: Mapping[str, float]) -> Unpinned:
    """Mark the nominal replay's slip episodes as no evidence (above): per run, the replay
    uncertainty ``replay_unc`` (which every later replay of the run attaches to its channels)
    and the nominal channels' ``unc`` are UNPINNED_UNC over the spans they cover.  Returns
    the prepared runs and nominal channels with that uncertainty (new values; those given are
    left as they are) and per run the (onset, end) of the unpinned episodes."""
    from host_tools.analyzer.prepare.run import BURN_IN_S
    out: list[list[tuple[float, float]]] = []
    out_preps: list[PreparedRun] = []
    out_nominal: list[dict[str, Channel]] = []
    for prep, given in zip(preps, nominal):
        chans = dict(given)
        found: list[tuple[float, float]] = []
        slips = list(prep.slip_episodes)
        unc = dict(prep.replay_unc or {})
        for a, b in prep.slip_episodes:
            onset = math.inf
            for c in POSE_CHANNELS:
                ch = chans.get(c)
                f = floors.get(c, 0.0)
                if ch is None or ch.unc is None or not f > 0:
                    continue
                m = (ch.t >= a) & (ch.t <= b) & (ch.unc > f)
                if m.any():
                    onset = min(onset, float(ch.t[m][0]))
            if math.isfinite(onset):
                found.append((onset, b))
        if not found and not slips:
            out.append([])
            out_preps.append(prep)
            out_nominal.append(chans)
            continue
        for c, ch in chans.items():
            if c not in FIT_CHANNELS or ch.t.size == 0:
                continue
            seg = ch.seg if ch.seg is not None else np.zeros(ch.t.size, int)
            mask = np.zeros(ch.t.size, bool)
            slip = np.zeros(ch.t.size, bool)
            if c in POSE_CHANNELS:
                for a, b in slips:
                    here = seg[np.argmin(np.abs(ch.t - a))]
                    mask |= (ch.t >= a) & (seg == here)
            else:
                for onset, b in found:
                    mask |= (ch.t >= onset) & (ch.t <= b + BURN_IN_S)
                for a, b in slips:
                    slip |= (ch.t >= a) & (ch.t <= b)
            if not (mask.any() or slip.any()):
                continue
            base = ch.unc if ch.unc is not None else np.zeros(ch.t.size)
            new = np.where(mask, UNPINNED_UNC, np.where(slip, np.maximum(base, SLIP_UNC), base))
            chans[c] = dataclasses.replace(ch, unc=new)
            unc[c] = (ch.t.copy(), new.copy())
        out_preps.append(dataclasses.replace(prep, replay_unc=unc))
        out_nominal.append(chans)
        out.append(found)
    return Unpinned(out_preps, out_nominal, out)
