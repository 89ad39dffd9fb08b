#!/usr/bin/env bash
# Sets up .venv if needed, then lint (ruff), types (mypy) and every test (pytest), end-to-end included.
set -euo pipefail
cd "$(dirname "$0")"
scripts/bootstrap.sh
echo "== ruff" && .venv/bin/ruff check . && .venv/bin/ruff format --check .
echo "== mypy" && .venv/bin/mypy
echo "== import contracts" && .venv/bin/lint-imports
echo "== pytest" && exec .venv/bin/pytest "$@"
