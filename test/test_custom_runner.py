"""Unity test runner of this project (PlatformIO `test_framework = custom`).

It is PlatformIO's own Unity runner with two changes:

- The Unity library comes from .deps/unity, which scripts/setup.sh extracts from Debian's
  ntpsec source package (Unity 2.5.1, MIT), so the tests run offline. Where that folder is
  absent (an online user who skipped the setup), the runner falls back to the registry's
  throwtheswitch/Unity.
- Under simavr, which prints the simulated UART0 one line at a time with the newline shown as
  a trailing '.', that '.' is removed before the line is parsed, so failure messages read as
  Unity wrote them.
"""
import os

from platformio.test.runners.unity import UnityTestRunner

_PROJECT_DIR = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
_LOCAL_UNITY = os.path.join(_PROJECT_DIR, ".deps", "unity")


class CustomTestRunner(UnityTestRunner):
    if os.path.isfile(os.path.join(_LOCAL_UNITY, "library.json")):
        EXTRA_LIB_DEPS = ["symlink://" + _LOCAL_UNITY]
    else:
        EXTRA_LIB_DEPS = ["throwtheswitch/Unity@^2.5.1"]

    def _under_simavr(self):
        command = self.project_config.get(
            f"env:{self.test_suite.env_name}", "test_testing_command", None
        )
        return bool(command) and "simavr" in " ".join(command)

    def parse_test_case(self, line):
        line = line.strip()
        if line.endswith(".") and self._under_simavr():
            line = line[:-1]
        return super().parse_test_case(line)
