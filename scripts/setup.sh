#!/usr/bin/env bash
# Create .venv at the repository root and install fd_monitor (editable) with ROS 2 Jazzy from
# the PyPI wheels, cvxpy + Clarabel, rosbags/mcap and the dev tools. Idempotent: a second run
# only reinstalls when setup.py changed.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
cd "$root"
python="${PYTHON:-python3}"
if [ ! -x .venv/bin/python ]; then
  echo "fd_monitor setup: creating .venv with $($python --version 2>&1)"
  "$python" -m venv .venv
fi
stamp=.venv/.fd_monitor_setup
want="$(cat setup.py package.xml | sha256sum | cut -d' ' -f1)"
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ]; then
  echo "fd_monitor setup: installing dependencies into .venv (a few minutes the first time)"
  log=.venv/pip-install.log
  if ! { .venv/bin/python -m pip install --upgrade pip \
         && .venv/bin/python -m pip install -e ".[ros,dev]"; } > "$log" 2>&1; then
    grep -v "^WARNING: Location" "$log" | tail -n 30 >&2
    echo "fd_monitor setup: pip install failed (full log: $log)" >&2
    exit 1
  fi
  echo "$want" > "$stamp"
fi
.venv/bin/python -c "import rclpy, cvxpy, rosbags, fd_monitor" \
  || { echo "fd_monitor setup: the installed environment does not import" >&2; exit 1; }
echo "fd_monitor setup: ready (.venv)"
