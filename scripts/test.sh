#!/usr/bin/env bash
# The whole test suite: sets up .venv if needed (scripts/setup.sh), then runs pytest, which
# also runs ruff and mypy (test/test_lint.py). Extra arguments go to pytest.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
cd "$root"
bash scripts/setup.sh
exec .venv/bin/python -m pytest "$@"
