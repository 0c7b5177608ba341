# Environment of the project's tools. Source it to use `pio` from your shell:
#   source scripts/env.sh
# It only sets variables; scripts/setup.sh installs what they point at.
_dd_root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
export PLATFORMIO_CORE_DIR="$_dd_root/.platformio"   # never the user's ~/.platformio
export PLATFORMIO_DISABLE_UPGRADE_CHECK=true
export PLATFORMIO_SETTING_ENABLE_TELEMETRY=no
export PLATFORMIO_DISABLE_PROGRESSBAR=true
export PATH="$_dd_root/.venv/bin:$PATH"
unset _dd_root
