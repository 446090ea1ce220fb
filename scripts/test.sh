#!/usr/bin/env bash
# Install (scripts/setup.sh) and run every test: the product's (test/) and the research's (research/tests/).
# Extra arguments go to pytest (e.g. -k node). The product's alone: .venv/bin/python -m pytest test
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/setup.sh
exec .venv/bin/python -m pytest test research/tests "$@"
