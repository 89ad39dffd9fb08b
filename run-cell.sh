#!/usr/bin/env bash
# Sets up .venv if needed and runs the default cell: gateway, controller emulator, tracker emulator.
# Options are passed to hrc-cell (e.g. --scenario two_people, --http-port 8081). Ctrl-C stops all.
set -euo pipefail
cd "$(dirname "$0")"
scripts/bootstrap.sh
exec .venv/bin/hrc-cell "$@"
