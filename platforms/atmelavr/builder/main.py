"""SCons build script of the local `atmelavr` stand-in (bare metal, avr-libc, no framework).

Targets: the default builds firmware.elf and firmware.hex and prints the size report with the
flash/SRAM check against the board's limits; `upload` writes the HEX with avrdude; `size`
prints avr-size's AVR memory usage.
"""
import glob
import os

from SCons.Script import (  # pylint: disable=import-error
    AlwaysBuild,
    Builder,
    Default,
    DefaultEnvironment,
)

env = DefaultEnvironment()
board = env.BoardConfig()

# firmware.elf / firmware.hex, as PlatformIO users expect (the build default is "program").
if env.get("PROGNAME", "program") == "program":
    env.Replace(PROGNAME="firmware")

env.Replace(
    AR="avr-gcc-ar",
    AS="avr-as",
    CC="avr-gcc",
    CXX="avr-g++",
    GDB="avr-gdb",
    OBJCOPY="avr-objcopy",
    RANLIB="avr-gcc-ranlib",
    SIZETOOL="avr-size",
    ARFLAGS=["rc"],
    PROGSUFFIX=".elf",
    # Section sizes for the flash/SRAM check (avr-size -A: one line per section).
    SIZEPROGREGEXP=r"^(?:\.text|\.data|\.bootloader)\s+(\d+).*",
    SIZEDATAREGEXP=r"^(?:\.data|\.bss|\.noinit)\s+(\d+).*",
    SIZECHECKCMD="$SIZETOOL -A -d $SOURCES",
    SIZEPRINTCMD="$SIZETOOL --mcu=$BOARD_MCU -C -d $SOURCES",
)

env.Append(
    ASFLAGS=["-x", "assembler-with-cpp", "-mmcu=$BOARD_MCU"],
    CCFLAGS=[
        "-Os",
        "-Wall",
        "-Wextra",
        "-ffunction-sections",
        "-fdata-sections",
        "-mmcu=$BOARD_MCU",
    ],
    CFLAGS=["-std=gnu11"],
    CXXFLAGS=["-std=gnu++11", "-fno-exceptions", "-fno-rtti", "-fno-threadsafe-statics"],
    CPPDEFINES=[("F_CPU", "$BOARD_F_CPU")],
    LINKFLAGS=["-Os", "-mmcu=$BOARD_MCU", "-Wl,--gc-sections"],
    LIBS=["m"],
    BUILDERS=dict(
        ElfToHex=Builder(
            action=env.VerboseAction(
                "$OBJCOPY -O ihex -R .eeprom $SOURCES $TARGET", "Building $TARGET"
            ),
            suffix=".hex",
        )
    ),
)

target_elf = env.BuildProgram()
target_hex = env.ElfToHex(os.path.join("$BUILD_DIR", "${PROGNAME}"), target_elf)

AlwaysBuild(
    env.Alias(
        "checkprogsize",
        target_elf,
        env.VerboseAction(env.CheckUploadSize, "Checking size $PIOMAINPROG"),
    )
)
AlwaysBuild(
    env.Alias("size", target_elf, env.VerboseAction("$SIZEPRINTCMD", "Calculating size $SOURCE"))
)


def _upload_port(*_args, **_kwargs):
    """Use upload_port if given, else the first USB serial port; with none, /dev/ttyACM0,
    so that avrdude itself reports that no board is attached.

    avrdude 7.1's `wiring` programmer ignores a failed open of the port and then retries
    forever; when the port does not exist, the upload runs as plain `stk500v2` (the same
    protocol without the reset pulse), which reports the missing port and exits at once."""
    if not env.subst("$UPLOAD_PORT"):
        ports = sorted(glob.glob("/dev/ttyACM*")) + sorted(glob.glob("/dev/ttyUSB*"))
        env.Replace(UPLOAD_PORT=ports[0] if ports else "/dev/ttyACM0")
    port = env.subst("$UPLOAD_PORT")
    if env.subst("$UPLOAD_PROTOCOL") == "wiring" and port.startswith("/") and not os.path.exists(port):
        env.Replace(UPLOAD_PROTOCOL="stk500v2")


env.Replace(
    UPLOADER="avrdude",
    UPLOADERFLAGS=[
        "-p", "$BOARD_MCU",
        "-c", "$UPLOAD_PROTOCOL",
        "-b", "$UPLOAD_SPEED",
        "-P", "$UPLOAD_PORT",
        "-D",
    ],
    UPLOADCMD="$UPLOADER $UPLOADERFLAGS -U flash:w:$SOURCES:i",
)
AlwaysBuild(
    env.Alias(
        "upload",
        target_hex,
        [
            env.VerboseAction(_upload_port, "Looking for upload port..."),
            env.VerboseAction("$UPLOADCMD", "Uploading $SOURCE"),
        ],
    )
)

Default([target_hex])
