#!/usr/bin/env bash
# Runs a command with an X display: the current one if there is one, else a virtual one (Xvfb).
set -euo pipefail
if [ -n "${DISPLAY:-}" ] && xdpyinfo >/dev/null 2>&1; then
  exec "$@"
fi
if ! command -v xvfb-run >/dev/null 2>&1; then
  echo "with-display: no X display and no xvfb-run (install xvfb: scripts/install-deps.sh)" >&2
  exit 1
fi
# -noreset: with no client left, an X server resets, and a window opened during the reset
# fails (VTK aborts): ctest starts and ends drawing tests at any moment
exec xvfb-run -a -s "-noreset -screen 0 1280x1024x24" "$@"
