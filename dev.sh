#!/usr/bin/env bash
# The project's two commands (see README):
#   ./dev.sh demo   set up .venv from the project's own files, then run the main job on the synthetic demo
#   ./dev.sh test   set up .venv if needed, then run the test suite
# Other verbs: setup (only create/update .venv), lint, igs ARGS... (run the CLI inside .venv).
set -euo pipefail
cd "$(dirname "$0")"

VENV=${IGS_VENV:-.venv}
PY=${PYTHON:-}
if [ -z "$PY" ]; then
  for cand in python3.11 python3; do
    if command -v "$cand" >/dev/null 2>&1 && "$cand" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))'; then
      PY=$cand; break
    fi
  done
fi
[ -n "$PY" ] || { echo "dev.sh: Python 3.11 is required (bpy 5.0.1 exists only for 3.11); set PYTHON=/path/to/python3.11" >&2; exit 2; }

setup() {
  # Re-install only when the pinned dependencies changed since the last successful install.
  local stamp="$VENV/.igs-installed" want
  want=$(sha256sum pyproject.toml | cut -d' ' -f1)
  if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ] && [ -x "$VENV/bin/python" ]; then
    return 0
  fi
  echo "== setting up $VENV (first run downloads ~1 GB: bpy, torch, pycolmap, opencv) =="
  [ -x "$VENV/bin/python" ] || "$PY" -m venv "$VENV"
  "$VENV/bin/python" -m pip install -q --upgrade pip
  # torch first and on its own: the pin resolves to the CPU build where one is offered.
  "$VENV/bin/python" -m pip install -q "torch==2.13.0"
  "$VENV/bin/python" -m pip install -q -e ".[dev]"
  echo "$want" > "$stamp"
}

cmd=${1:-}
[ $# -gt 0 ] && shift
case "$cmd" in
  setup) setup ;;
  demo)  setup; exec "$VENV/bin/igs" demo "$@" ;;
  test)  setup; exec "$VENV/bin/python" -m pytest -q "$@" ;;
  lint)  setup; exec "$VENV/bin/ruff" check . ;;
  igs)   setup; exec "$VENV/bin/igs" "$@" ;;
  *) echo "usage: ./dev.sh demo|test|setup|lint|igs ARGS..." >&2; exit 2 ;;
esac
