"""Firmware in the loop: record runs from the real firmware.elf in simavr.

``python -m host_tools.fil record --out RUN_DIR [--accel 48 --clamp off ...] [sim options]``
builds the simulator (:mod:`host_tools._build` target ``fil``) and, unless ``--elf`` is given, the firmware
(``pio run -e megaatmega2560``), starts ``.build/fil/fil`` (which prints the pty of the
simulated XBee link) and records through that pty with the telemetry logger
(:mod:`host_tools.logger`), exactly as from the radio.  The run folder then holds the logger's
files (meta.json, telemetry.csv, raw.bin, events.jsonl) and the simulator's (groundtruth.csv,
plant.csv, encoder_samples.csv, fil.json).  ``meta.json`` gets ``"source": "fil"`` and a
``"fil"`` section (simulator options, plant keys).  ``bench`` prints simulated seconds per
wall-clock second.  Usage and the file contents: docs/fil.md.
"""
from __future__ import annotations

import argparse
import contextlib
import fcntl
import json
import logging
import os
import queue
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

from host_tools import _build, _progress
from host_tools import logger as L
from host_tools import protocol as P

log = logging.getLogger("host_tools.fil")  # also when run as __main__

ROOT = Path(__file__).resolve().parents[1]
BUILD = ROOT / ".build" / "fil"
SIM = _build.TARGETS["fil"].output_path()
PIO_ELF = ROOT / ".pio" / "build" / "megaatmega2560" / "firmware.elf"
FREE_RECORDING_S = 5.0  # a recording without an experiment (and without --record-s), s


class FilError(Exception):
    """The simulator or the firmware could not be built or run."""


def _env() -> dict:
    env = dict(os.environ)
    env.setdefault("PLATFORMIO_CORE_DIR", str(ROOT / ".platformio"))
    env.setdefault("PLATFORMIO_DISABLE_UPGRADE_CHECK", "true")
    env.setdefault("PLATFORMIO_SETTING_ENABLE_TELEMETRY", "no")
    venv_bin = str(ROOT / ".venv" / "bin")
    if venv_bin not in env.get("PATH", "").split(os.pathsep):
        env["PATH"] = venv_bin + os.pathsep + env.get("PATH", "")
    return env


def build_sim() -> Path:
    """Builds .build/fil/fil (host_tools._build target fil; no-op when up to date). FilError
    with the compiler output."""
    try:
        return _build.build("fil")
    except _build.NativeBuildError as exc:
        raise FilError(str(exc)) from None


@contextlib.contextmanager
def pio_build_lock():
    """Held around every ``pio run -e megaatmega2560`` of this checkout by the host tools and
    their tests: two at once in the one .pio tree (tests run in parallel processes) would
    race on SCons' database and on the ELF being read while it is rewritten."""
    BUILD.mkdir(parents=True, exist_ok=True)
    with open(BUILD / ".pio-build.lock", "w") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def build_firmware() -> Path:
    """Builds the megaatmega2560 firmware and returns a private copy of its ELF
    (.build/fil/firmware.elf: other builds of the shared tree cannot change it mid-run; the
    copy is replaced atomically, so a simulator starting meanwhile reads a whole file)."""
    pio = shutil.which("pio", path=_env()["PATH"])
    if pio is None:
        raise FilError("PlatformIO (pio) not found: run scripts/setup.sh, then source scripts/env.sh")
    with pio_build_lock():
        for attempt in range(3):  # the tree is shared: another build of .pio may be under way
            r = subprocess.run([pio, "run", "-e", "megaatmega2560"], capture_output=True, text=True, env=_env(), cwd=ROOT)
            if r.returncode == 0 and PIO_ELF.exists():
                break
            time.sleep(3)
        if r.returncode != 0 or not PIO_ELF.exists():
            raise FilError(f"pio run -e megaatmega2560 failed:\n{(r.stdout + r.stderr)[-3000:]}")
        dst = BUILD / "firmware.elf"
        tmp = BUILD / f".firmware.elf.{os.getpid()}.tmp"
        shutil.copyfile(PIO_ELF, tmp)
        os.replace(tmp, dst)
    return dst


def nominal_plant_keys() -> dict[str, float]:
    """The simulator's plant keys that make lib/slipmodel's plant the nominal model's robot: the
    table's parameters with the nominal normal forces (the wheels' mass on the axle, the load
    transfer at the table's h plus the spin-up's share k^; one definition,
    ``host_tools.analyzer.replay.normal_forces.plant_config``).  They come first on the command
    line, so a ``--set`` of the caller's overrides them."""
    from host_tools.analyzer.replay.normal_forces import plant_config
    from host_tools.params import ROBOT
    cfg = plant_config(ROBOT, {})
    keys = {f"robot.{k}": float(v) for k, v in cfg.robot.items() if float(v) != float(ROBOT[k])}
    for name, params in cfg.effects.items():
        keys[f"{name}.enabled"] = 1.0
        keys.update({f"{name}.{p}": float(v) for p, v in params.items()})
    keys.update(cfg.keys)
    return keys


def model_plant_keys(model: dict[str, Any]) -> dict[str, float]:
    """The simulator's plant keys of an analyzer model (model.json, ``host_tools.model``): its
    parameters and effects with the nominal normal forces on top, the plant the analyzer
    replayed it with (``plant_config``: a fitted ``load_transfer`` h is a centre-of-mass height,
    k^ h_s added; the wheels' mass on the axle of the model's robot).  Every robot key is
    given, so they override :func:`nominal_plant_keys`."""
    from host_tools import model as M
    from host_tools.analyzer.effects import ADDED_PARAMETER_EFFECTS
    from host_tools.analyzer.replay.normal_forces import plant_config
    from host_tools.params import ROBOT
    keys = M.plant_keys(model)
    robot = {**ROBOT, **{k: float(v) for k, v in model.get("robot", {}).items()}}
    effects = {e: p for e, p in model.get("effects", {}).items()
               if e not in ADDED_PARAMETER_EFFECTS}   # folded into "robot" already
    cfg = plant_config(robot, effects)
    keys.update({f"robot.{k}": float(v) for k, v in cfg.robot.items()})
    for name, params in cfg.effects.items():
        keys[f"{name}.enabled"] = 1.0
        keys.update({f"{name}.{p}": float(v) for p, v in params.items()})
    keys.update(cfg.keys)
    return keys


def nominal_plant_args() -> list[str]:
    """``--set K=V`` options of :func:`nominal_plant_keys`."""
    return sim_args(nominal_plant_keys())


class Sim:
    """One simulator process. ``args``: extra command-line options of .build/fil/fil.

    With ``--lockstep`` among them the host holds the board clock (:meth:`run_to`,
    :meth:`release`, :meth:`hold`; sim/fil/lockstep.cpp): the simulator starts held at 50 ms
    of board time (:meth:`start_hold`), and the port of :meth:`wrap_port` counts the host's
    bytes written (each grant waits for all of them) and read (:meth:`caught_up`)."""

    def __init__(self, elf: str | Path, run_dir: str | Path, args: list[str] | None = None,
                 sim: str | Path = SIM, start_timeout_s: float = 10.0):
        self.run_dir = Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.log_path = self.run_dir / "fil.log"
        self._log = open(self.log_path, "w")
        self.cmd = ([str(sim), str(elf), "--run-dir", str(self.run_dir)] + nominal_plant_args()
                    + [str(a) for a in (args or [])])
        self.lockstep = "--lockstep" in self.cmd
        self.bytes_written = 0  # host bytes written to the pty through wrap_port's port
        self.bytes_read = 0  # robot bytes read from the pty through wrap_port's port
        self.stepping = self.lockstep  # held from the start (the first hold: start_hold)
        self.held_at = -1.0  # board time of the last hold
        self.last_frame_t = -1.0  # at the last hold: the time stamp of the robot's last whole telemetry frame
        self.up_at_hold = 0  # at the last hold: the robot's bytes written into the pty so far
        self._at: "queue.Queue[str]" = queue.Queue()
        self._lock = threading.Lock()  # one control line and its hold at a time
        self.proc = subprocess.Popen(self.cmd, stdout=subprocess.PIPE, stderr=self._log, text=True,
                                     stdin=subprocess.PIPE if self.lockstep else None)
        self.pty = self._read_pty(start_timeout_s)

    def _read_pty(self, timeout: float) -> str:
        found: list[str] = []

        def reader():
            for line in self.proc.stdout:
                if line.startswith("PTY "):
                    found.append(line.split(None, 1)[1].strip())
                    return

        t = threading.Thread(target=reader, daemon=True)
        t.start()
        t.join(timeout)
        if not found:
            self.kill()
            raise FilError(f"simulator did not report its pty; {self.cmd}\n{self.log()}")

        # keep draining stdout (simavr prints to it) so the process never blocks on a full pipe;
        # the lockstep holds ("AT <board time> <host bytes>") go to the queue
        def drain():
            for line in self.proc.stdout:
                if line.startswith("AT "):
                    self._at.put(line)
        threading.Thread(target=drain, daemon=True).start()
        return found[0]

    # ---- lockstep (--lockstep)
    def wrap_port(self, port: Any) -> Any:
        """The host's port to the pty, counting the bytes written (every grant names them)."""
        return _CountingPort(port, self)

    def _control(self, line: str, wait: bool = True, timeout_s: float = 30.0) -> float | None:
        if not self.lockstep:
            raise FilError("the simulator runs without --lockstep: no holds")
        with self._lock:
            if self.held_at < 0:  # the hold at the start comes first
                self._await_hold("the start", timeout_s)
            try:
                assert self.proc.stdin is not None
                self.proc.stdin.write(line + "\n")
                self.proc.stdin.flush()
            except (BrokenPipeError, ValueError, OSError):
                raise FilError(f"the simulator has ended\n{self.log()}") from None
            if not wait:
                return None
            return self._await_hold(repr(line), timeout_s)

    def _await_hold(self, what: str, timeout_s: float, block: bool = True) -> float:
        t_end = time.monotonic() + timeout_s
        while True:
            try:
                at = self._at.get(timeout=0.1 if block else 0.0).split()
                self.last_frame_t = float(at[3])
                self.up_at_hold = int(at[4])
                self.held_at = float(at[1])
                return self.held_at
            except queue.Empty:
                if not block:
                    return -1.0
                if self.proc.poll() is not None or time.monotonic() > t_end:
                    raise FilError(f"the simulator did not hold ({what})\n{self.log()}") from None

    def start_hold(self, timeout_s: float = 30.0) -> float:
        """The hold the simulator starts in (50 ms of board time; it runs there once the host
        has written into the pty): its board time."""
        with self._lock:
            return self.held_at if self.held_at >= 0 else self._await_hold("the start", timeout_s)

    def caught_up(self) -> bool:
        """While held: the host has read every byte the robot sent before the hold (all it will
        get until the next grant), so what it does next is the same in every run."""
        if self.held_at < 0:
            with self._lock:
                if self.held_at < 0 and self._await_hold("the start", 0.0, block=False) < 0:
                    return False
        return self.bytes_read >= self.up_at_hold

    def hold(self, grid_s: float) -> float:
        """Stop the board clock at its next multiple of ``grid_s``; returns that board time."""
        t = self._control(f"hold {grid_s:.7f}")
        self.stepping = True
        assert t is not None
        return t

    def run_to(self, t_s: float) -> float:
        """While held: deliver every byte written so far at this board time, run to board time
        ``t_s`` and hold there; returns the board time of the hold."""
        got = self._control(f"run {t_s:.7f} {self.bytes_written}")
        assert got is not None
        return got

    def release(self) -> None:
        """While held: run on, paced by --realtime."""
        if self.stepping and self.proc.poll() is None:
            self._control("free", wait=False)
        self.stepping = False

    def log(self) -> str:
        self._log.flush()
        return self.log_path.read_text()

    def wait(self, timeout: float = 30.0) -> int:
        try:
            code = self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.kill()
            raise FilError(f"simulator still running after {timeout} s; killed\n{self.log()}") from None
        self._log.close()
        if code != 0:
            raise FilError(f"simulator exited with {code}\n{self.log()}")
        return code

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()

    def summary(self) -> dict:
        with open(self.run_dir / "fil.json") as fh:
            return json.load(fh)


class _CountingPort:
    """A pyserial-like port that counts the bytes written into ``sim.bytes_written`` and those
    read into ``sim.bytes_read``."""

    def __init__(self, port: Any, sim: Sim):
        self._port, self._sim = port, sim

    def write(self, data: bytes) -> int | None:
        n = self._port.write(data)
        self._sim.bytes_written += len(data)  # pyserial writes all of it or raises
        return n

    def read(self, size: int = 1) -> bytes:
        data = self._port.read(size)
        self._sim.bytes_read += len(data)
        return data

    def __getattr__(self, name: str) -> Any:
        return getattr(self._port, name)


class FilLogger(L.Logger):
    """The telemetry logger, with the simulator's description added to meta.json.
    ``board_s``: the recording's length in simulated seconds (the robot's clock, from the first
    telemetry row): a simulator slower than real time (a loaded machine) would otherwise have
    its run cut by the wall clock, which stays the backstop (``record_s``)."""

    def __init__(self, *a, fil_meta: dict | None = None, board_s: float | None = None, **kw):
        super().__init__(*a, **kw)
        self.fil_meta = fil_meta or {}
        self.board_s = board_s
        self._board_t0: float | None = None

    def _should_stop(self) -> bool:
        if self.board_s is not None and self.last_t_s is not None:
            if self._board_t0 is None:
                self._board_t0 = self.last_t_s
            elif self.last_t_s - self._board_t0 >= self.board_s:
                self.end_reason = self.end_reason or f"recorded {self.board_s:g} s"
                return True
        return super()._should_stop()

    def _meta(self) -> dict:
        meta = super()._meta()
        meta["source"] = "fil"
        meta["fil"] = self.fil_meta
        return meta


def sim_args(keys: dict[str, float] | None = None, **opts: Any) -> list[str]:
    """Command-line options of the simulator: keys -> --set K=V; opts name=value -> --name value
    (underscores become dashes; True -> a bare flag; None/False -> left out)."""
    out: list[str] = []
    for k, v in (keys or {}).items():
        out += ["--set", f"{k}={v!r}"]
    for k, v in opts.items():
        if v is None or v is False:
            continue
        flag = "--" + k.replace("_", "-")
        out += [flag] if v is True else [flag, str(v)]
    return out


def record(out: str | Path, elf: str | Path, experiment: dict | None = None, clamp: bool | None = None,
           mu: tuple[float, float] | None = None, args: list[str] | None = None,
           record_s: float | None = None, timeout_s: float = 60.0,
           controller: str | None = None, model: dict | None = None,
           on_row=None) -> tuple[int, L.Logger, dict]:
    """Runs the simulator and records through its pty with the logger (``controller``:
    the velocity loop the logger sets with SetController before the Start, None: the
    firmware's default; ``model``: SetModel values, host_tools.model.firmware_model;
    ``on_row``: called with each telemetry row, e.g. the live view's publish; ``record_s``:
    simulated seconds, the wall clock allowing ``timeout_s`` more). Returns
    (logger exit code, logger, fil.json)."""
    out = Path(out)
    if controller is not None and controller not in P.definition().enums["controller"]:
        raise FilError(f"controller '{controller}' is not one of "
                       f"{', '.join(sorted(P.definition().enums['controller']))}")
    from host_tools.logger.runfolder import clear_failed
    clear_failed(str(out))  # a retry replaces a failed recording
    for f in ("telemetry.csv", "groundtruth.csv"):
        if (out / f).exists():
            raise FilError(f"{out / f} already exists; refusing to overwrite a recorded run")
    if record_s is None:
        record_s = (experiment["duration"] + 5.0) if experiment else FREE_RECORDING_S
    args = list(args or [])
    if "--t-end" not in args:  # the simulator's own limit (board time) must not cut the recording
        args += ["--t-end", f"{record_s + 10.0:g}"]
    sim = Sim(elf, out, args)
    d = P.definition()

    def open_port():
        import serial
        return serial.serial_for_url(sim.pty, baudrate=d.baud, timeout=0.05, write_timeout=0.5)

    lg = FilLogger(str(out), open_port, sim.pty, d.baud, experiment=experiment, clamp=clamp, mu=mu,
                   board_s=record_s, record_s=record_s + timeout_s, controller=controller, status=False, d=d, model=model, on_row=on_row,
                   fil_meta={"command": sim.cmd[1:], "elf": str(elf)})
    try:
        code = lg.run()
    finally:
        try:
            sim.wait(timeout_s)
        except FilError:
            sim.kill()
            raise
    summary = sim.summary()
    # the summary (speed, ISR cycles, ...) also in meta.json, for a reader of the run alone
    lg.fil_meta["summary"] = {k: summary[k] for k in ("sim_s_per_wall_s", "encoder_isr", "tasks",
                                                     "encoder_check", "slip", "link") if k in summary}
    lg.write_meta()
    return code, lg, summary


def bench(elf: str | Path, accel: float = 48.0, duration: float = 2.0) -> int:
    """Free-running simulator (no pacing) with a host that keeps time by the robot's telemetry
    (a heartbeat every 0.1 s of board time, so the run is the same at any speed); prints
    simulated seconds per wall-clock second."""
    import tempfile

    import serial
    d = P.definition()
    running_flag = 1 << d.flags["status"]["running"]
    with tempfile.TemporaryDirectory() as tmp:
        sim = Sim(elf, Path(tmp) / "run", ["--realtime", "0"])
        port = serial.serial_for_url(sim.pty, baudrate=d.baud, timeout=0.01)
        dec = P.StreamDecoder(d.version, d.max_payload)
        seq = 0
        t0 = time.monotonic()
        try:
            start = d.encode("Start", 2, {"profile": "straight", "wheel_accel": accel, "accel_time": 0.5,
                                          "duration": duration, "radius": 0.0})
            seq = 3
            last_hb, last_start, seen_run, done = 0.0, -1.0, False, False
            while not done and time.monotonic() - t0 < 120:
                try:
                    data = port.read(4096)
                except serial.SerialException:
                    break  # the simulator ended (t_end)
                for f in dec.feed(data):
                    msg, raws = d.unpack(f)
                    if msg.name != "Telemetry":
                        continue
                    t = d.physical(msg, raws)
                    run = bool(int(t["status"]) & running_flag)
                    if not seen_run and not run and t["t_us"] - last_start >= 0.1:
                        # (re)send until the robot reports running: bytes sent before its USART
                        # is initialised are lost, as on the radio
                        port.write(d.encode("SetClamp", 1, {"on": 0}) + start)
                        last_start = t["t_us"]
                    if t["t_us"] - last_hb >= 0.1:
                        port.write(d.encode("Heartbeat", seq & 0xFFFF))
                        seq += 1
                        last_hb = t["t_us"]
                    seen_run = seen_run or run
                    done = seen_run and not run
        finally:
            port.close()
            sim.wait(60)
        s = sim.summary()
    if not done:
        raise FilError("the experiment did not run to its end in the benchmark")
    fs = [e["code"] for e in s["failsafe_events"]]
    print(f"simulated {s['sim_s']:.3f} s (boot, straight line {accel:g} rad/s^2 for {duration:g} s, clamp off) "
          f"in {s['wall_s'] - s['wall_waiting_for_host_s']:.3f} s wall: {s['sim_s_per_wall_s']:.2f} simulated s per "
          f"wall s (free running, 16 MHz, plant step {s['plant_dt_s'] * 1e3:g} ms); failsafe codes seen: "
          f"{', '.join(map(str, fs)) or 'none'}")
    print(f"encoder ISR {s['encoder_isr']['mean_cycles']:.1f} cycles per edge mean, {s['encoder_isr']['max_cycles']} max, "
          f"{s['encoder_isr']['calls']} edges; task max cycles during the experiment: "
          + ", ".join(f"{k} {v['experiment_max_cycles']} ({v['experiment_overruns']} overruns)"
                      for k, v in s["tasks"].items() if isinstance(v, dict)))
    return 0


# ================================================================================ CLI


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.description = ("firmware in the loop: the real firmware.elf in simavr against the plant, "
                     "recorded through the simulated XBee link by the telemetry logger "
                     "(docs/fil.md)")
    sub = p.add_subparsers(dest="fil_cmd", metavar="SUBCOMMAND")
    r = sub.add_parser("record", help="run the firmware in the simulator and record a run",
                       description="Run firmware.elf in simavr against lib/slipmodel's plant and "
                       "record it through the simulated XBee pty with the telemetry logger: a "
                       "run folder with the logger's files (meta.json, telemetry.csv, raw.bin, "
                       "events.jsonl) and the simulator's (groundtruth.csv, plant.csv, "
                       "encoder_samples.csv, fil.json). Exit status: 0 done, 1 the recording "
                       "failed, 2 bad input or the simulator/firmware could not be built or run.")
    r.add_argument("--out", required=True, metavar="RUN_DIR",
                   help="run folder to write (must not hold a recorded run)")
    r.add_argument("--elf", help="firmware ELF (default: build megaatmega2560)")
    r.add_argument("--experiment", default="straight",
                   choices=sorted(P.definition().enums["profile"]) + ["none"],
                   help="the experiment profile sent with Start (default straight; none: record "
                   "without starting one, for --record-s)")
    r.add_argument("--accel", type=float, default=48.0, help="wheel acceleration, rad/s^2 (default 48)")
    r.add_argument("--accel-time", type=float, default=0.5,
                   help="acceleration phase, s (default 0.5)")
    r.add_argument("--duration", type=float, default=2.0, help="experiment length, s (default 2)")
    r.add_argument("--radius", type=float, default=0.0,
                   help="arc / figure-eight radius, m (+ = left; default 0)")
    r.add_argument("--clamp", choices=["on", "off"],
                   help="send SetClamp before starting (default: the firmware's setting)")
    r.add_argument("--mu-s", type=float, help="static friction coefficient sent with SetMu "
                   "(with --mu-k)")
    r.add_argument("--mu-k", type=float, help="kinetic friction coefficient sent with SetMu "
                   "(with --mu-s)")
    r.add_argument("--controller", choices=sorted(P.definition().enums["controller"]),
                   help="the cascade's velocity loop, sent as SetController before the Start "
                   "(default: the firmware's, improved)")
    r.add_argument("--model", metavar="MODEL_JSON", help="an analyzer model.json (ddmodel/1): its parameters "
                   "and effects go to the simulated plant, its mu_s/mu_k (SetMu) and wheel radius, half track, "
                   "back-EMF ratio and voltage drop (SetModel) to the firmware")
    r.add_argument("--record-s", type=float, help="free recording length, s (with --experiment "
                   "none; default: the experiment's length + 5 s)")
    from host_tools.interop import live
    live.add_option(r)
    r.add_argument("sim_options", nargs=argparse.REMAINDER,
                   help="after '--': options of .build/fil/fil (see .build/fil/fil --help)")
    b = sub.add_parser("bench", help="print simulated seconds per wall-clock second",
                       description="Run the simulator free (no pacing) through one straight-line "
                       "experiment and print simulated seconds per wall-clock second and the "
                       "ISR and task cycles.")
    b.add_argument("--elf", help="firmware ELF (default: build megaatmega2560)")
    b.add_argument("--accel", type=float, default=48.0, help="wheel acceleration, rad/s^2 (default 48)")
    b.add_argument("--duration", type=float, default=2.0, help="experiment length, s (default 2)")


def _elf(a: argparse.Namespace) -> Path:
    return Path(a.elf) if a.elf else build_firmware()


def main(a: argparse.Namespace) -> int:
    if getattr(a, "fil_cmd", None) is None:
        log.error("give a subcommand: record or bench")
        return 2
    pub = None
    try:
        if a.fil_cmd == "record" and getattr(a, "live", None) is not None:
            from host_tools.interop import live  # a taken port is refused before any build
            pub = live.start(a.live, L.TelemetryColumns(P.definition()).columns)
        build_sim()
        elf = _elf(a)
        if a.fil_cmd == "record":
            opts = [o for o in a.sim_options if o != "--"]
            exp = None
            if a.experiment != "none":
                exp = {"profile": a.experiment, "wheel_accel": a.accel, "accel_time": a.accel_time,
                       "duration": a.duration, "radius": a.radius}
                P.definition().raw_values("Start", exp)
            if (a.mu_s is None) != (a.mu_k is None):
                raise P.ProtocolError("--mu-s and --mu-k go together")
            mu = (a.mu_s, a.mu_k) if a.mu_s is not None else None
            fw_model = None
            if a.model:
                from host_tools import model as M
                if mu is not None:
                    raise P.ProtocolError("--model and --mu-s/--mu-k exclude each other")
                m = M.load_model(a.model)
                mu, fw_model = M.firmware_commands(m, a.model)
                opts = sim_args(model_plant_keys(m)) + opts
            clamp = None if a.clamp is None else a.clamp == "on"
            on_row, bar = _record_progress(exp, a.record_s, pub)
            with bar:
                code, lg, s = record(a.out, elf, exp, clamp, mu, opts, record_s=a.record_s,
                                     controller=a.controller, model=fw_model, on_row=on_row)
            print(f"{a.out}: {lg.stats['telemetry_rows']} telemetry rows, {s['groundtruth']['rows']} ground-truth "
                  f"rows; {s['sim_s']:.2f} simulated s at {s['sim_s_per_wall_s']:.2f} simulated s per wall s; "
                  f"logger: {lg.end_reason}")
            return code
        return bench(elf, a.accel, a.duration)
    except (FilError, P.ProtocolError, L.LoggerError, ValueError) as exc:
        log.error("%s", exc)
        return 2
    finally:
        if pub:
            pub.close()


def _record_progress(exp: dict | None, record_s: float | None, pub: Any
                     ) -> tuple[Any, _progress.Progress]:
    """``fil record``'s progress bar on a terminal: the simulated seconds recorded (board time
    since the first telemetry row) out of the experiment's length (or --record-s, or the 5 s
    of a free recording); and the row callback that draws it and feeds the live view."""
    total = exp["duration"] if exp else FREE_RECORDING_S
    if record_s is not None:
        total = min(total, record_s) if exp else record_s
    bar = _progress.Progress(total, "fil record", logger=log, bar_format=(
        "{desc}: {percentage:3.0f}%|{bar}| {n:.1f}/{total:g} simulated s [{elapsed}<{remaining}]"))
    first: list[float] = []

    def on_row(row: dict) -> None:
        if pub:
            pub.publish(row)
        if not first:
            first.append(row["t_s"])
        bar.set(min(row["t_s"] - first[0], total))
    return on_row, bar


if __name__ == "__main__":
    from host_tools.__main__ import setup_logging
    setup_logging(0)
    ap = argparse.ArgumentParser(prog="python -m host_tools.fil", description=__doc__.split("\n\n")[0])
    add_arguments(ap)
    sys.exit(main(ap.parse_args()))
