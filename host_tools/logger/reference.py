"""The reference the firmware tracked, for meta.json ``reference`` (the analyzer's closed-loop
replay reads it).

The firmware reports in every telemetry frame the board time of the run's first tick
(``ref_t0_s``, the reference's time 0) and, in drive mode, the Drive target its last outer step
used (``v_cmd_m_s``, ``omega_cmd_rad_s``: the last Drive as received, or 0 after the command
timeout).  :class:`ReferenceTracker` turns that into

* a Start profile: ``{"kind": "line"|"arc"|"figure_eight", "accel": m/s^2, "cruise": m/s,
  "radius": m, "t0_s": board time}`` -- the profile the firmware builds from the Start command
  (``accel = r wheel_accel``, ``cruise = r wheel_accel accel_time``, r the wheel radius it
  reported in Params), the form host_tools/truth writes;
* drive mode: ``{"kind": "drive", "t0_s", "accel", "alpha", "cmd_timeout_s", "outer_s",
  "commands": [{"t_s", "v", "omega"}, ...]}`` -- the targets as the firmware latched them, each
  with the board time of the outer tick that first used it (frames are 20 ms apart and outer
  ticks 50 ms, so a change between two frames names one tick; ``ambiguous`` counts the changes
  seen across a gap of lost frames wide enough to hold two ticks, which then take the later one).

Only the first run of a recording is described (``runs`` counts them).
"""
from __future__ import annotations

import math
from typing import Any

from host_tools import protocol as P

_PROFILE_KINDS = {"straight": "line", "arc": "arc", "figure_eight": "figure_eight"}
_U32_S = 2**32 * 1e-6  # the board's microsecond clock wraps after this many seconds


class ReferenceTracker:
    """Fed every telemetry row (the logger's dict), in order."""

    def __init__(self, d: P.Definition):
        flags = d.flags["status"]
        self._running_bit = 1 << flags["running"]
        self._drive_bit = 1 << flags["drive_mode"]
        self.outer_s = next(t["period_us"] for t in d.tasks() if t["name"] == "outer") / 1e6
        self.runs = 0
        self.t0_s: float | None = None
        self.drive: bool | None = None
        self.commands: list[dict[str, float]] = []
        self.ambiguous = 0
        self._was_running = False
        self._last: tuple[float, float, float] | None = None  # (t_s, v, omega) of the last frame
        self._done = False

    def row(self, row: dict[str, Any]) -> None:
        status = int(row.get("status", 0))
        running = bool(status & self._running_bit)
        if running and not self._was_running:
            self.runs += 1
            if self.runs == 1:
                self._begin(row, bool(status & self._drive_bit))
        elif not running and self._was_running and self.runs == 1:
            self._done = True
        self._was_running = running
        if running and self.runs == 1 and not self._done and self.drive:
            self._drive_row(row)

    def _begin(self, row: dict[str, Any], drive: bool) -> None:
        t = float(row["t_s"])
        # ref_t0 is on the board's wrapping u32 clock; the row's time is unwrapped
        back = (t - float(row["ref_t0_s"])) % _U32_S
        self.t0_s = round(t - back, 6)
        self.drive = drive

    def _drive_row(self, row: dict[str, Any]) -> None:
        assert self.t0_s is not None  # _begin set it: a drive run has begun
        t = float(row["t_s"])
        cmd = (float(row["v_cmd_m_s"]), float(row["omega_cmd_rad_s"]))
        if self._last is None:  # the first frame of the run: the start tick's target
            self.commands.append({"t_s": self.t0_s, "v": cmd[0], "omega": cmd[1]})
        elif cmd != self._last[1:]:
            k_hi = math.floor((t - self.t0_s) / self.outer_s + 1e-9)
            k_lo = math.floor((self._last[0] - self.t0_s) / self.outer_s + 1e-9) + 1
            if k_hi > k_lo:
                self.ambiguous += 1
            self.commands.append({"t_s": round(self.t0_s + k_hi * self.outer_s, 6),
                                  "v": cmd[0], "omega": cmd[1]})
        self._last = (t, *cmd)

    def reference(self, start: dict[str, Any] | None, robot_r: float, limits: dict[str, float]
                  ) -> dict[str, Any] | None:
        """meta.json ``reference``, or None before a run started."""
        if self.t0_s is None:
            return None
        if self.drive:
            return {"kind": "drive", "t0_s": self.t0_s, "accel": float(limits["accel"]),
                    "alpha": float(limits["alpha"]), "cmd_timeout_s": float(limits["cmd_timeout"]),
                    "outer_s": self.outer_s, "commands": list(self.commands),
                    "ambiguous": self.ambiguous, "runs": self.runs}
        if start is None:
            return None
        kind = _PROFILE_KINDS[start["profile"]]
        accel = robot_r * float(start["wheel_accel"])
        out = {"kind": kind, "accel": accel, "cruise": accel * float(start["accel_time"]),
               "t0_s": self.t0_s, "runs": self.runs}
        if kind != "line":
            out["radius"] = float(start["radius"])
        return out
