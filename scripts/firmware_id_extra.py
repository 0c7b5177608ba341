"""PlatformIO extra script (post) of the AVR environments: defines FIRMWARE_ID for the
firmware's own sources (src/) from the checkout's revision, as host_tools/firmware_id.py
encodes it (the short hash, a dirty marker; 0 = unknown outside a git checkout)."""
import sys

Import("env", "projenv")  # noqa: F821  (SCons globals)

sys.path.insert(0, env.subst("$PROJECT_DIR"))  # noqa: F821
from host_tools import firmware_id  # noqa: E402  pylint: disable=wrong-import-position

fid, text = firmware_id.revision(env.subst("$PROJECT_DIR"))  # noqa: F821
projenv.Append(CPPDEFINES=[("FIRMWARE_ID", f"0x{fid:08X}UL")])  # noqa: F821
if not env.GetOption("silent"):  # noqa: F821
    print(f"FIRMWARE_ID 0x{fid:08X} ({text})")
