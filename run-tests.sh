#!/usr/bin/env bash
# Sets up .venv if needed, then lint (ruff), types (mypy), the import contracts and every test (pytest), end-to-end
# included. Every step runs; the exit status is non-zero if any of them failed (pytest's arguments: "$@").
set -uo pipefail
cd "$(dirname "$0")"
scripts/bootstrap.sh || exit
failed=()
step() {
    local name=$1
    shift
    echo "== $name"
    "$@" || failed+=("$name")
}
step "ruff" .venv/bin/ruff check .
step "ruff format" .venv/bin/ruff format --check .
step "mypy" .venv/bin/mypy
step "import contracts" .venv/bin/lint-imports
# Two workers (pytest-xdist): the end-to-end tests one after another on one, every other module on the other
# (tests/conftest.py groups them); "-n 0" among the arguments runs everything in this process.
step "pytest" .venv/bin/pytest -n 2 --dist loadgroup "$@"
if ((${#failed[@]})); then
    printf '\n== FAILED: %s\n' "${failed[*]}"  # a new line first: an extension's exit message may lack its own
    exit 1
fi
printf '\n== all passed\n'
