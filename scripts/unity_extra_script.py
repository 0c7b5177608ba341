"""PlatformIO extra script of the provisioned Unity library (copied into .deps/unity).

Unity's sources must see the same unity_config.h as the tests: this script defines
UNITY_INCLUDE_CONFIG_H for the library and adds the folder of the project's unity_config.h
(the one PlatformIO generates, or test/<group>/unity_config.h) to its include path.
"""
import os

Import("env")  # noqa: F821  pylint: disable=undefined-variable

env.Append(CPPDEFINES=["UNITY_INCLUDE_CONFIG_H"])  # noqa: F821
try:
    Import("projenv")  # noqa: F821
except Exception:  # pylint: disable=broad-except
    projenv = None
if projenv is not None:  # noqa: F821
    for path in projenv.get("CPPPATH", []):  # noqa: F821
        path = projenv.subst(path)  # noqa: F821
        if os.path.isfile(os.path.join(path, "unity_config.h")):
            env.Prepend(CPPPATH=[path])  # noqa: F821
            break
