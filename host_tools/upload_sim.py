"""A simulated Arduino Mega 2560 to upload to: the board's stk500v2 bootloader in simavr.

``python -m host_tools.upload_sim [--uart0-link PATH] [--uart2-link PATH]`` builds
``sim/upload/upload_sim.c`` (:mod:`host_tools._build` target ``upload_sim``), starts it with
Debian ``arduino-core-avr``'s ``stk500boot_v2_mega2560.hex`` and the Mega 2560's fuses from the
same package's ``boards.txt`` (both unpacked by ``scripts/setup.sh`` into
``.deps/unpacked/arduino-core-avr``), and prints the two pseudo-terminals: UART0 (the USB
serial port: opening it resets the MCU into the bootloader, as DTR does on the board) and UART2
(the XBee link). Then

    pio run -e megaatmega2560 -t upload --upload-port <UART0>

uploads the firmware with avrdude (``wiring`` protocol) and the bootloader starts it; its
telemetry comes out of UART2. Usage and what it proves: docs/firmware.md, "Uploading".
"""
from __future__ import annotations

import argparse
import re
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from host_tools import _build

ROOT = Path(__file__).resolve().parents[1]
ARDUINO_AVR = ROOT / ".deps" / "unpacked" / "arduino-core-avr" / "usr" / "share" / "arduino" / "hardware" / "arduino" / "avr"
BOARD_BASE = "mega"  # boards.txt: Arduino Mega or Mega 2560 ...
BOARD = BOARD_BASE + ".menu.cpu.atmega2560"  # ... with its ATmega2560 menu entry
AVRDUDE = ROOT / ".platformio" / "packages" / "tool-avrdude" / "bin" / "avrdude"


class UploadSimError(Exception):
    """The bootloader, the simulator or avrdude is missing or failed."""


@dataclass(frozen=True)
class BoardImage:
    """The board's bootloader and fuses, as Debian's arduino-core-avr ships them."""
    bootloader: Path
    hfuse: int
    lfuse: int
    efuse: int
    upload_protocol: str
    upload_speed: int


def board_image(avr_dir: Path = ARDUINO_AVR) -> BoardImage:
    """Reads boards.txt of the unpacked arduino-core-avr: the Mega 2560's bootloader file, fuses
    and upload settings. UploadSimError when the package is not unpacked (run scripts/setup.sh)."""
    boards = avr_dir / "boards.txt"
    if not boards.is_file():
        raise UploadSimError(f"{boards} is missing: run scripts/setup.sh (it unpacks Debian's arduino-core-avr)")
    kv: dict[str, str] = {}
    lines = [ln.split("=", 1) for ln in boards.read_text(encoding="utf-8", errors="replace").splitlines()
             if "=" in ln and not ln.lstrip().startswith("#")]
    # the board's keys, then the CPU menu entry's, which override them (Arduino's boards.txt rule)
    for prefix in (BOARD_BASE + ".", BOARD + "."):
        for k, v in lines:
            k = k.strip()
            if k.startswith(prefix) and not (prefix == BOARD_BASE + "." and k.startswith(BOARD_BASE + ".menu.")):
                kv[k[len(prefix):]] = v.strip()
    try:
        img = BoardImage(bootloader=avr_dir / "bootloaders" / kv["bootloader.file"],
                         hfuse=int(kv["bootloader.high_fuses"], 0), lfuse=int(kv["bootloader.low_fuses"], 0),
                         efuse=int(kv["bootloader.extended_fuses"], 0),
                         upload_protocol=kv["upload.protocol"], upload_speed=int(kv["upload.speed"]))
    except (KeyError, ValueError) as exc:
        raise UploadSimError(f"{boards}: no usable entry {BOARD}.* ({exc})") from None
    if not img.bootloader.is_file():
        raise UploadSimError(f"{img.bootloader} is missing: run scripts/setup.sh")
    return img


def hex_bytes(path: str | Path) -> dict[int, int]:
    """Address -> byte of an Intel HEX file (records 00-05)."""
    out: dict[int, int] = {}
    base = 0
    for row, line in enumerate(Path(path).read_text().splitlines(), 1):
        line = line.strip()
        if not line:
            continue
        raw = bytes.fromhex(line[1:])
        if line[0] != ":" or len(raw) != raw[0] + 5 or sum(raw) & 0xFF:
            raise UploadSimError(f"{path}:{row}: not an Intel HEX record")
        n, addr, typ, data = raw[0], (raw[1] << 8) | raw[2], raw[3], raw[4:-1]
        if typ == 0:
            out.update({base + addr + i: b for i, b in enumerate(data)})
        elif typ == 1:
            break
        elif typ in (2, 4):
            base = int.from_bytes(data[:2], "big") << (4 if typ == 2 else 16)
        del n
    return out


_DUMP_ROW = re.compile(r"^([0-9a-f]{4,6})\s+((?:[0-9a-f]{2}\s+){1,16})", re.I)


def parse_dump(text: str) -> dict[int, int]:
    """Address -> byte of avrdude's terminal ``dump`` output."""
    out: dict[int, int] = {}
    for line in text.splitlines():
        m = _DUMP_ROW.match(line.strip())
        if m:
            a = int(m.group(1), 16)
            for i, b in enumerate(m.group(2).split()):
                out[a + i] = int(b, 16)
    return out


class SimBoard:
    """One upload_sim process (a context manager). ``uart0``/``uart2``: the pty paths;
    ``events``: its output lines ("RESET t=...", "APP t=...")."""

    def __init__(self, image: BoardImage | None = None, flash_out: str | Path | None = None,
                 t_max: float = 600.0, uart0_link: str | None = None, uart2_link: str | None = None):
        self.image = image or board_image()
        try:
            exe = _build.build("upload_sim")
        except _build.NativeBuildError as exc:
            raise UploadSimError(str(exc)) from None
        cmd = [str(exe), "--boot", str(self.image.bootloader), "--hfuse", hex(self.image.hfuse),
               "--lfuse", hex(self.image.lfuse), "--efuse", hex(self.image.efuse), "--t-max", str(t_max)]
        if flash_out:
            cmd += ["--flash-out", str(flash_out)]
        if uart0_link:
            cmd += ["--uart0-link", uart0_link]
        if uart2_link:
            cmd += ["--uart2-link", uart2_link]
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        self.lines: list[str] = []
        self._cv = threading.Condition()
        threading.Thread(target=self._reader, daemon=True).start()
        self.uart0 = self._wait_for("UART0 ")
        self.uart2 = self._wait_for("UART2 ")

    def _reader(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            with self._cv:
                self.lines.append(line.rstrip("\n"))
                self._cv.notify_all()
        with self._cv:
            self._cv.notify_all()

    def _wait_for(self, prefix: str, timeout: float = 20.0, after: int = 0) -> str:
        end = time.monotonic() + timeout
        with self._cv:
            while True:
                for line in self.lines[after:]:
                    if line.startswith(prefix):
                        return line[len(prefix):].strip()
                if self.proc.poll() is not None or time.monotonic() > end:
                    raise UploadSimError(f"upload_sim printed no '{prefix.strip()}':\n" + "\n".join(self.lines))
                self._cv.wait(0.1)

    def wait_event(self, prefix: str, after: int = 0, timeout: float = 20.0) -> str:
        """The first output line after the first ``after`` lines that starts with ``prefix``."""
        return self._wait_for(prefix, timeout, after)

    def stop(self) -> str:
        """Stops the simulator; returns its last line ("END ...")."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        time.sleep(0.05)
        with self._cv:
            return self.lines[-1] if self.lines else ""

    def __enter__(self) -> "SimBoard":
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


def avrdude(port: str, *args: str, image: BoardImage | None = None, stdin: str | None = None,
            timeout: float = 120.0) -> subprocess.CompletedProcess:
    """The provisioned avrdude with the board's part, protocol, speed and port (the flags the
    atmelavr platform gives it for ``-t upload``), plus ``args``."""
    img = image or board_image()
    if not AVRDUDE.exists():
        raise UploadSimError(f"{AVRDUDE} is missing: run scripts/setup.sh")
    cmd = [str(AVRDUDE), "-p", "atmega2560", "-c", img.upload_protocol, "-b", str(img.upload_speed), "-P", port,
           "-D", *args]
    return subprocess.run(cmd, input=stdin, capture_output=True, text=True, timeout=timeout)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m host_tools.upload_sim", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--uart0-link", help="also make a symlink PATH -> the USB serial pty")
    ap.add_argument("--uart2-link", help="also make a symlink PATH -> the XBee pty")
    a = ap.parse_args(argv)
    try:
        board = SimBoard(uart0_link=a.uart0_link, uart2_link=a.uart2_link)
    except UploadSimError as exc:
        print(f"upload_sim: {exc}", file=sys.stderr)
        return 2
    print(f"USB serial (UART0): {board.uart0}\nXBee (UART2): {board.uart2}\n"
          f"upload: pio run -e megaatmega2560 -t upload --upload-port {a.uart0_link or board.uart0}\n"
          "Ctrl-C stops.", flush=True)
    def _stop(*_):
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, _stop)  # a terminated driver stops the simulator too
    seen = 0
    try:
        while board.proc.poll() is None:
            time.sleep(0.2)
            for line in board.lines[seen:]:
                print(line, flush=True)
            seen = len(board.lines)
    except KeyboardInterrupt:
        pass
    print(board.stop())
    return 0


if __name__ == "__main__":
    sys.exit(main())
