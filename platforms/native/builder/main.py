"""SCons build script of the local `native` stand-in: host gcc/g++, program `program`."""
from SCons.Script import AlwaysBuild, Default, DefaultEnvironment  # pylint: disable=import-error

env = DefaultEnvironment()

env.Replace(
    AR="ar",
    AS="as",
    CC="gcc",
    CXX="g++",
    OBJCOPY="objcopy",
    RANLIB="ranlib",
    SIZETOOL="size",
    PROGNAME="program",
)

target_bin = env.BuildProgram()

# `pio run -e native -t exec` runs the program.
AlwaysBuild(env.Alias("exec", target_bin, "$SOURCE"))

Default([target_bin])
