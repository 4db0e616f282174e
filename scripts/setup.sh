#!/usr/bin/env bash
# Create .venv at the repository root and install exactly requirements.lock into it (ROS 2
# Jazzy from the PyPI wheels, cvxpy + Clarabel, rosbags/mcap, the dev tools; every version and
# sha256 pinned), then fd_monitor itself (editable, no dependencies). Idempotent: a second run
# reinstalls only when the lock, setup.py or package.xml changed, or the venv no longer matches
# the lock (scripts/lockcheck.py); packages the lock does not name are removed.
# Refresh the lock with `bash scripts/lock.sh`.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
cd "$root"
python="${PYTHON:-python3}"
if [ ! -x .venv/bin/python ]; then
  echo "fd_monitor setup: creating .venv with $($python --version 2>&1)"
  "$python" -m venv .venv
fi
stamp=.venv/.fd_monitor_setup
want="$(cat requirements.lock setup.py package.xml | sha256sum | cut -d' ' -f1)"
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ] \
   || ! .venv/bin/python scripts/lockcheck.py 2>/dev/null; then
  echo "fd_monitor setup: installing requirements.lock into .venv (a few minutes the first time)"
  log=.venv/pip-install.log
  # --require-hashes: every file pip installs must match a hash of the lock; --no-deps: the
  # lock is the whole set (pip resolves nothing). The editable install cannot be hash-checked;
  # it builds with the locked setuptools (--no-build-isolation) and installs nothing else.
  if ! { .venv/bin/python -m pip install --require-hashes --no-deps -r requirements.lock \
         && .venv/bin/python scripts/lockcheck.py --extras \
            | xargs -r .venv/bin/python -m pip uninstall -y \
         && .venv/bin/python -m pip install --no-deps --no-build-isolation -e . \
         && .venv/bin/python scripts/lockcheck.py; } > "$log" 2>&1; then
    grep -v "^WARNING: Location" "$log" | tail -n 30 >&2
    echo "fd_monitor setup: pip install failed (full log: $log)" >&2
    exit 1
  fi
  echo "$want" > "$stamp"
fi
.venv/bin/python -c "import rclpy, cvxpy, rosbags, fd_monitor" \
  || { echo "fd_monitor setup: the installed environment does not import" >&2; exit 1; }
echo "fd_monitor setup: ready (.venv)"
