#!/usr/bin/env bash
# The whole test suite: sets up .venv if needed (scripts/setup.sh), then runs pytest, which
# also runs ruff, mypy and the docs build (test/test_lint.py, test/test_docs.py). Extra
# arguments go to pytest.
#
# It runs on two pytest-xdist workers (one per core of a 2-core machine; one on a 1-core
# machine), each test file on one worker, the longest files first (test/conftest.py), and
# each worker in a DDS domain of its own. FD_TEST_WORKERS=N sets the number (1 = one
# process, no xdist; at most 4). A failed test is run once more (pytest-rerunfailures): a
# live test over DDS can miss a deadline on a loaded machine; a rerun shows as "R" and in
# the summary, and a test that fails twice fails the run.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
cd "$root"
bash scripts/setup.sh
cores="$(nproc 2>/dev/null || echo 1)"
workers="${FD_TEST_WORKERS:-$(( cores < 2 ? 1 : 2 ))}"
if [ "$workers" -gt 4 ]; then workers=4; fi
if [ "$workers" -le 1 ]; then
  exec .venv/bin/python -m pytest --reruns 1 "$@"
fi
exec .venv/bin/python -m pytest -n "$workers" --dist loadfile --reruns 1 "$@"
