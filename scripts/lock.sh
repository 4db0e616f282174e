#!/usr/bin/env bash
# Refresh requirements.lock, the exact set (versions and sha256 hashes) that scripts/setup.sh
# installs into .venv: setup.py's dependencies with the `ros` and `dev` extras, plus the venv's
# own tools (pip, the installer; uv, the resolver this script runs). One universal resolution
# (every platform and Python the wheels cover, markers where they differ), from the default
# index only: a machine's local mirrors never leak into the lock.
#
#   bash scripts/lock.sh              keep the pins, add or drop only what setup.py changed
#   bash scripts/lock.sh --upgrade    move every package to its newest release
#
# Then `bash scripts/setup.sh` installs the new lock (its stamp includes the lock).
# Extra arguments go to `uv pip compile` (e.g. --upgrade-package numpy).
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
cd "$root"
uv="${UV:-}"
if [ -z "$uv" ] && [ -x .venv/bin/uv ]; then
  uv=.venv/bin/uv                     # the locked uv, installed by setup.sh
fi
if [ -z "$uv" ]; then                 # no venv yet (or a broken lock): a throw-away uv
  tmp="$(mktemp -d)"
  trap 'rm -rf "$tmp"' EXIT
  "${PYTHON:-python3}" -m venv "$tmp/venv"
  "$tmp/venv/bin/python" -m pip install --quiet uv
  uv="$tmp/venv/bin/uv"
fi
printf 'pip\nuv\n' | UV_CUSTOM_COMPILE_COMMAND="bash scripts/lock.sh" \
  "$uv" pip compile setup.py - --extra ros --extra dev --universal --generate-hashes \
  --quiet -o requirements.lock "$@"
echo "fd_monitor lock: requirements.lock holds $(grep -c '^[A-Za-z0-9].*==' requirements.lock) pins"
