#!/usr/bin/env bash
# The whole test suite: sets up .venv if needed (scripts/setup.sh), then runs pytest, which
# also runs ruff, mypy and the docs build (test/test_lint.py, test/test_docs.py). Extra
# arguments go to pytest.
#
# The suite runs in parallel (pytest-xdist, one worker per core, at most 4; each test file on
# one worker, so module fixtures are made once): most of its time is spent waiting on DDS and
# on the nodes' own processes, which a second worker fills. Each worker has a DDS domain of its
# own (test/conftest.py). FD_TEST_WORKERS=0 runs it in this one process.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
cd "$root"
bash scripts/setup.sh
workers="${FD_TEST_WORKERS:-$(nproc 2>/dev/null || echo 2)}"
if [ "$workers" -gt 4 ]; then workers=4; fi
if [ "$workers" -le 1 ]; then
  exec .venv/bin/python -m pytest "$@"
fi
exec .venv/bin/python -m pytest -n "$workers" --dist loadfile "$@"
