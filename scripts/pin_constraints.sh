#!/usr/bin/env bash
# Regenerate constraints.txt (the pinned versions CI and the README's install use) from a fresh
# environment installed with the newest allowed versions:
#   bash scripts/pin_constraints.sh
set -euo pipefail
cd "$(dirname "$0")/.."
tmp=$(mktemp -d)
python3 -m venv "$tmp/venv"
. "$tmp/venv/bin/activate"
python -m pip install --quiet --upgrade pip
python -m pip install --quiet torch==2.13.0 --index-url https://download.pytorch.org/whl/cpu
python -m pip install --quiet -e ".[dev]"
{
  echo "# Pinned versions for CI and the README's install (pip install -e \".[dev]\" -c constraints.txt)."
  echo "# torch is installed first by its own line (the CPU build); regenerate with scripts/pin_constraints.sh."
  python -m pip freeze --exclude-editable | grep -v -E "^torch=="
} > constraints.txt
rm -rf "$tmp"
