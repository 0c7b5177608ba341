"""Upload proven end to end, in simulation: Debian arduino-core-avr's stk500v2 bootloader for the
Mega 2560 runs in simavr (sim/upload/upload_sim.c, host_tools.upload_sim) with the board's fuses;
`pio run -e megaatmega2560 -t upload --upload-port <pty>` writes the firmware through it with
avrdude (wiring protocol) and verifies it; an explicit avrdude read of the flash equals
firmware.hex; the bootloader starts the firmware, whose telemetry and Params (with the build's
FIRMWARE_ID: the checkout's revision) arrive on the XBee UART.

Everything it needs is provisioned by scripts/setup.sh: it fails (never skips) when something is
missing."""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import time
from pathlib import Path


from host_tools import firmware_id
from host_tools import protocol as P
from host_tools import upload_sim as U
from host_tools.fil import _env, pio_build_lock

ROOT = Path(__file__).resolve().parents[2]
HEX = ROOT / ".pio" / "build" / "megaatmega2560" / "firmware.hex"


def _pio() -> str:
    pio = shutil.which("pio", path=_env()["PATH"])
    assert pio, "pio not found: run scripts/setup.sh"
    return pio


def _read_xbee(path: str, telemetry: int, send: bytes = b"", timeout: float = 60.0) -> list[P.Frame]:
    """The frames on the XBee pty until ``telemetry`` Telemetry frames and a Params came (the
    simulation may run slower than real time on a loaded machine: counted in frames)."""
    import tty
    d = P.definition()
    fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    try:
        tty.setraw(fd)
        if send:
            os.write(fd, send)
        dec = P.StreamDecoder()
        frames: list[P.Frame] = []
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            try:
                frames += dec.feed(os.read(fd, 4096))
            except BlockingIOError:
                time.sleep(0.01)
            names = [d.unpack(f)[0].name for f in frames]
            if names.count("Telemetry") >= telemetry and "Params" in names:
                break
        return frames
    finally:
        os.close(fd)


def test_the_board_image_is_the_mega_2560s():
    img = U.board_image()
    assert img.bootloader.name == "stk500boot_v2_mega2560.hex"
    assert img.upload_protocol == "wiring" and img.upload_speed == 115200  # as platformio.ini
    assert img.hfuse & 1 == 0, "BOOTRST programmed: the reset vector is the bootloader's"
    data = U.hex_bytes(img.bootloader)
    assert min(data) == 0x3E000 and max(data) < 0x40000  # the 4 K-word boot section (BOOTSZ 00)


def test_upload_verify_readback_and_the_firmware_runs(tmp_path):
    d = P.definition()
    t0 = time.monotonic()
    with pio_build_lock():  # the .pio tree is shared with the other test processes
        build = subprocess.run([_pio(), "run", "-e", "megaatmega2560"], capture_output=True, text=True,
                               env=_env(), cwd=ROOT)
    assert build.returncode == 0, build.stdout[-3000:] + build.stderr[-3000:]
    flash_out = tmp_path / "flash.bin"
    with U.SimBoard(flash_out=flash_out, t_max=300) as board:
        t_up = time.monotonic()
        with pio_build_lock():
            up = subprocess.run([_pio(), "run", "-v", "-e", "megaatmega2560", "-t", "upload", "--upload-port",
                                 board.uart0], capture_output=True, text=True, env=_env(), cwd=ROOT, timeout=180)
            if up.returncode == 0:  # what was uploaded (the tree is shared)
                shutil.copyfile(HEX, tmp_path / "firmware.hex")
        upload_s = time.monotonic() - t_up
        out = up.stdout + up.stderr
        assert up.returncode == 0, out[-4000:]
        image = U.hex_bytes(tmp_path / "firmware.hex")
        n = len(image)
        assert re.search(rf"\b{n} bytes of flash written", out), out[-3000:]
        assert re.search(rf"\b{n} bytes of flash verified", out), out[-3000:]
        assert re.search(r"avrdude\S* -p atmega2560 -c wiring -b 115200 -P " + re.escape(board.uart0), out), out[-3000:]
        # the port's open reset the MCU into the bootloader, which started the firmware after it
        reset = board.wait_event("RESET ")
        assert "pc=0x3e000" in reset
        n_lines = board.lines.index("RESET " + reset)
        board.wait_event("APP ", after=n_lines)

        # the firmware runs: telemetry and Params on the XBee UART (RequestParams answered)
        frames = _read_xbee(board.uart2, 25, send=d.encode("RequestParams", 0))
        names = [d.unpack(f)[0].name for f in frames]
        tel = [d.physical(*d.unpack(f)) for f in frames if d.unpack(f)[0].name == "Telemetry"]
        assert len(tel) >= 25, names
        t_s = [t["t_us"] for t in tel]
        assert all(abs(b - a - 0.020) < 0.002 for a, b in zip(t_s, t_s[1:])), t_s  # every 20 ms of board time
        params = [d.physical(*d.unpack(f)) for f in frames if d.unpack(f)[0].name == "Params"]
        assert params, names
        fid = int(params[-1]["firmware_id"])
        want, text = firmware_id.revision(ROOT)
        assert fid == want, (firmware_id.describe(fid), text)
        assert text != "unknown"

        # explicit read-back of the firmware's range with avrdude (terminal mode: a reset again)
        before_read = len(board.lines)
        t_rd = time.monotonic()
        rd = U.avrdude(board.uart0, "-t", stdin=f"dump flash 0 {max(image) + 1}\nquit\n")
        read_s = time.monotonic() - t_rd
        assert rd.returncode == 0, rd.stdout[-2000:] + rd.stderr[-2000:]
        back = U.parse_dump(rd.stdout)
        assert len(back) == max(image) + 1
        diff = [a for a, b in image.items() if back.get(a) != b]
        assert not diff, f"{len(diff)} bytes differ, first at 0x{diff[0]:05x}"
        # and the firmware starts again after that session
        board.wait_event("RESET ", after=before_read)
        board.wait_event("APP ", after=before_read)
        end = board.stop()
    flash = flash_out.read_bytes()
    assert all(flash[a] == b for a, b in image.items())  # the simulated flash itself
    boot = U.hex_bytes(U.board_image().bootloader)
    assert all(flash[a] == b for a, b in boot.items())  # the bootloader is intact
    phases = dict(re.findall(r"(Writing|Reading) \| #+ \| 100% ([\d.]+)s", out))
    print(f"\nupload {n} bytes: avrdude writing {phases.get('Writing')} s, verify reading {phases.get('Reading')} s; "
          f"pio run -t upload {upload_s:.1f} s wall; "
          f"explicit read-back of {len(back)} bytes: {read_s:.1f} s; {len(tel)} telemetry frames; "
          f"firmware_id {firmware_id.describe(fid)}; {end}; test {time.monotonic() - t0:.1f} s")
