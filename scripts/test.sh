#!/usr/bin/env bash
# The whole test suite: sets up .venv if needed (scripts/setup.sh), then runs pytest, which
# also runs ruff, mypy and the docs build (test/test_lint.py, test/test_docs.py). Extra
# arguments go to pytest.
#
# FD_TEST_WORKERS=N (N >= 2, at most 4) runs it on pytest-xdist workers, each test file on one
# worker and each worker in a DDS domain of its own (test/conftest.py): 8-11 min instead of
# ~14 on 2 cores, but a second worker's load still makes two timing-bound live tests fail now
# and then (test_nodes_burst, test_robot_live), so the default is one process.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
cd "$root"
bash scripts/setup.sh
workers="${FD_TEST_WORKERS:-1}"
if [ "$workers" -gt 4 ]; then workers=4; fi
if [ "$workers" -le 1 ]; then
  exec .venv/bin/python -m pytest "$@"
fi
exec .venv/bin/python -m pytest -n "$workers" --dist loadfile "$@"
