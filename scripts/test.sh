#!/usr/bin/env bash
# Install (scripts/setup.sh) and run every test; extra arguments go to pytest (e.g. -k node).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
exec .venv/bin/python -m pytest test "$@"
