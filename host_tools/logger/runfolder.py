"""The run folder a recording session writes (``ddrun/1`` through host_tools.runfmt).

:class:`RunFolderMixin` is the part of :class:`~host_tools.logger.session.Logger` that owns
the files: checking ``--out`` before the port is opened (and keeping a reserve file there so
that a full disk still leaves room for the end), meta.json (the parameters the robot
reported, the commands and the link statistics), telemetry.csv, raw.bin and events.jsonl,
their periodic flush, and closing them (cutting a line torn by a failed write).
"""
from __future__ import annotations

import json
import os
from typing import TYPE_CHECKING, Any

from host_tools import firmware_id, runfmt
from host_tools.logger.errors import LoggerError
from host_tools.logger.frames import shortest_f32

if TYPE_CHECKING:  # the state and methods the other parts provide (parts.py)
    from host_tools.logger.parts import SessionParts
else:
    SessionParts = object

RESERVE_BYTES = 256 * 1024  # kept free in the run folder for the final meta.json and events
RESERVE_NAME = ".logger-reserve"
RUN_FILES = ("meta.json", "telemetry.csv", "raw.bin", "events.jsonl")
# A recording that failed before its experiment or drive ran: meta.json says "failed" (the
# reason) and this file is in the folder; a retry with the same --out replaces the folder's files.
FAILED_NAME = "FAILED"
# the firmware in the loop's files (host_tools.fil), replaced with a failed recording's
SIM_FILES = ("groundtruth.csv", "plant.csv", "encoder_samples.csv", "fil.json", "fil.log")


def failed_reason(out: str) -> str | None:
    """The reason a run folder is marked failed (its FAILED file and meta.json "failed"), else
    None."""
    try:
        with open(os.path.join(out, "meta.json")) as fh:
            reason = json.load(fh).get("failed")
    except (OSError, ValueError, AttributeError):
        return None
    return str(reason) if reason and os.path.exists(os.path.join(out, FAILED_NAME)) else None


def clear_failed(out: str) -> None:
    """Remove a failed recording's files (only when the folder is marked failed)."""
    if failed_reason(out) is None:
        return
    for f in RUN_FILES[1:] + SIM_FILES + (FAILED_NAME, "meta.json"):  # meta.json last: the mark
        try:
            os.remove(os.path.join(out, f))
        except FileNotFoundError:
            pass


def describe_experiment(cmd: dict[str, Any]) -> str:
    p, a, ta, T = cmd["profile"], cmd["wheel_accel"], cmd["accel_time"], cmd["duration"]
    base = f"{a:g} rad/s^2 wheel acceleration for {ta:g} s, then hold; {T:g} s in all"
    if p == "straight":
        return "straight line, " + base
    if p == "arc":
        return f"arc of radius {cmd['radius']:g} m, " + base
    return f"figure eight of loop radius {cmd['radius']:g} m, " + base


class RunFolderMixin(SessionParts):
    """Files of one recording session."""

    def prepare_out(self) -> None:
        """Create the run folder and check that it can be written, before the port is
        opened; LoggerError (exit 2) when --out is unusable."""
        shown = runfmt.display(self.out)
        if os.path.exists(self.out) and not os.path.isdir(self.out):
            raise LoggerError(f"--out {shown} exists and is not a folder", 2)
        self._created_out = not os.path.exists(self.out)
        try:
            clear_failed(self.out)  # a retry replaces a failed recording
        except OSError as exc:
            raise LoggerError(f"--out {shown}: cannot replace the failed recording there: "
                              f"{exc.strerror or exc}", 2) from None
        for f in RUN_FILES:  # meta.json alone is a run someone made (or is making)
            if os.path.lexists(os.path.join(self.out, f)):
                raise LoggerError(f"{runfmt.display(os.path.join(self.out, f))} already exists; "
                                  "refusing to overwrite a recorded run", 2)
        reserve = os.path.join(self.out, RESERVE_NAME)
        try:
            os.makedirs(self.out, exist_ok=True)
            with open(reserve, "wb") as fh:
                fh.write(bytes(RESERVE_BYTES))
                fh.flush()
                os.fsync(fh.fileno())
        except OSError as exc:
            self._free_reserve()
            raise LoggerError(f"--out {shown} cannot be written: {exc.strerror or exc}", 2) from None

    def _remove_if_created(self) -> None:
        """Nothing recorded (the port never opened): remove the folder if this session made it."""
        self._free_reserve()
        if getattr(self, "_created_out", False):
            try:
                os.rmdir(self.out)
            except OSError:
                pass

    def mark_failed(self, reason: str) -> None:
        """The experiment or drive never ran: meta.json "failed" and the FAILED file say so, and
        a retry with the same --out replaces the folder's files."""
        self.failed = reason
        try:
            with open(os.path.join(self.out, FAILED_NAME), "w") as fh:
                fh.write(f"this recording failed and holds no experiment: {reason}\n"
                         "a recording with the same --out replaces it\n")
        except OSError:
            pass

    def _free_reserve(self) -> None:
        try:
            os.remove(os.path.join(self.out, RESERVE_NAME))
        except OSError:
            pass

    def _open_files(self) -> None:
        self.writer = runfmt.RunWriter(self.out, self._meta_for_writer(), columns=self.cols.columns)
        self.raw = open(os.path.join(self.out, "raw.bin"), "wb")
        self.events = open(os.path.join(self.out, "events.jsonl"), "w")

    def _meta(self) -> dict[str, Any]:
        dflt = self.d.robot_defaults
        meta: dict[str, Any] = {
            "format": runfmt.FORMAT,
            "experiment": self.description or (describe_experiment(self.experiment) if self.experiment
                                               else "free recording (no experiment command sent)"),
            "source": "robot",
            "robot": dict(dflt["robot"]),
            "motor": dict(dflt["motor"]),
            "encoder_ppr": dflt["encoder_ppr"],
            "periods_s": {t["name"]: round(t["period_us"] * 1e-6, 9) for t in self.d.tasks()},
            # this project's firmware ramps a clamped wheel's duty every millisecond and
            # reports the duty of the frame's moment (docs/firmware.md)
            "duty_ramp": True,
        }
        if getattr(self, "failed", None):
            meta["failed"] = self.failed
        mu_ok = self.mu is not None and self._acked("SetMu")
        clamp_ok = self.clamp is not None and self._acked("SetClamp")
        if mu_ok and self.mu is not None:
            meta["robot"]["mu_s"], meta["robot"]["mu_k"] = self.mu
        meta["torque_clamp"] = bool(self.clamp) if clamp_ok else False
        p = self.params
        # Params received after the configuration commands: what the robot now uses
        fresh = p is not None and self._config_sent and self._params_count > self._params_before_config
        if p is not None:
            for k in meta["robot"]:
                if k in ("mu_s", "mu_k") and mu_ok and not fresh:
                    continue  # Params predate SetMu: the commanded (acknowledged) values apply
                meta["robot"][k] = shortest_f32(p[k])
            for k in meta["motor"]:
                meta["motor"][k] = shortest_f32(p[k])
            meta["encoder_ppr"] = int(p["encoder_ppr"])
            meta["periods_s"] = {k: round(p[f"{k}_period_us"] * 1e-6, 9) for k in ("inner", "outer", "telemetry")}
            if fresh or not clamp_ok:
                meta["torque_clamp"] = bool(p["clamp_on"])
        variant = self._variant_reported(fresh)
        if variant is not None:
            meta["controller_variant"] = variant
        if p is not None:  # the torque->duty map's fit (SetModel); meta "motor" already includes it
            meta["motor_model"] = {"ke_ratio": shortest_f32(p["ke_ratio"]), "drop_v": shortest_f32(p["drop_v"])}
        ref = self.reftrack.reference(self.experiment, meta["robot"]["r"], self._drive_limits_in_force())
        if ref is not None:
            meta["reference"] = ref
        meta["commands"] = self.commands
        self.stats["frames"] = self.dec.frames
        meta["logger"] = dict(
            self.stats, port=self.port_name, baud=self.baud, protocol_version=self.d.version,
            host_t0_unix_s=round(getattr(self, "_t0_unix", 0.0), 6),
            crc_errors=self.dec.crc_errors, rejected_blocks=dict(self.dec.rejected),
            params_source="robot" if p is not None else "defaults (the robot never reported Params)",
            firmware_id=(firmware_id.describe(p["firmware_id"]) if p is not None else None),
            robot_baud=(p["baud"] if p is not None else None),
            end_reason=self.end_reason or "recording")
        return meta

    def _variant_reported(self, fresh: bool) -> str | None:
        """The velocity loop for meta.json: the robot's Params when they follow the
        configuration (or none was sent), else the acknowledged SetController, else None."""
        ctl_ok = self.controller is not None and self._acked("SetController")
        p = self.params
        if p is not None and (fresh or not ctl_ok):
            names = {v: k for k, v in self.d.enums["controller"].items()}
            return names.get(int(p["controller"]), f"unknown (code {int(p['controller'])})")
        return self.controller if ctl_ok else None

    def _drive_limits_in_force(self) -> dict[str, Any]:
        """The drive limits: the acknowledged SetDriveLimits, else the firmware's boot defaults
        (protocol.json drive)."""
        if self.drive_limits is not None and self._acked("SetDriveLimits"):
            return dict(self.drive_limits)
        return {k: self.d.spec["drive"][k] for k in ("accel", "alpha", "cmd_timeout")}

    def _acked(self, name: str) -> bool:
        return any(c["command"] == name and c["result"] == "ok" for c in self.commands)

    def _meta_for_writer(self) -> dict[str, Any]:
        return self._meta()

    def write_meta(self) -> None:
        path = os.path.join(self.out, "meta.json")
        meta = runfmt.validate_meta(self._meta(), path)
        # beside and renamed, in a file created exclusively: never a half-written meta.json
        runfmt.write_atomic(path, json.dumps(meta, indent=2) + "\n")

    def event(self, kind: str, **kw: Any) -> None:
        kw = {"host_t_s": round(self.clock() - self._t0, 4), "kind": kind, **kw}
        self.events.write(json.dumps(kw) + "\n")

    def _flush(self) -> None:
        self._last_flush = self.clock()
        self.writer.flush()
        self.raw.flush()
        self.events.flush()

    def _close_files(self) -> bool:
        """Write the "end" event, flush and close the files.  Returns True when one failed."""
        failed = False
        for name in ("writer", "raw", "events"):
            obj = getattr(self, name, None)
            if obj is None:
                continue
            try:
                if name == "events":
                    self.event("end", reason=self.end_reason or "stopped",
                               pending_bytes=self.dec.pending())
                obj.flush()
            except OSError as exc:
                failed = True
                self._write_error = self._write_error or exc
            try:
                obj.close()
            except Exception:
                failed = True
        return failed

    def _trim_after_failure(self) -> None:
        """After a failed write: whole lines only, and the rows that reached the disk counted."""
        for f in ("telemetry.csv", "events.jsonl"):
            self._cut_torn_line(os.path.join(self.out, f))
        try:  # meta.json states the rows that reached the disk
            with open(os.path.join(self.out, "telemetry.csv"), "rb") as fh:
                on_disk = max(0, fh.read().count(b"\n") - 1)
            self.stats["rows_lost_at_write_failure"] = self.stats["telemetry_rows"] - on_disk
            self.stats["telemetry_rows"] = on_disk
        except OSError:
            pass

    def _cut_torn_line(self, path: str) -> None:
        """After a failed write: cut a text file back to its last complete line."""
        try:
            with open(path, "rb+") as fh:
                data = fh.read()
                keep = data.rfind(b"\n") + 1
                if keep < len(data):
                    fh.truncate(keep)
        except OSError:
            pass
