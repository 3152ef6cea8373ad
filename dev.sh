#!/usr/bin/env bash
# The project's two commands (see README):
#   ./dev.sh demo   set up .venv from the project's own files, then run the main job on the synthetic demo
#   ./dev.sh test   set up .venv if needed, then run the test suite
#   ./dev.sh test-blender   the add-on in a real Blender 5.2 window (root; builds a cached Debian root)
#   ./dev.sh test-py311     the backend suite (a chosen subset) on Python 3.11 with bpy 5.0.1, in .venv-py311
# Other verbs: setup (only create/update .venv), lint, igs ARGS... (run the CLI inside .venv).
set -euo pipefail
cd "$(dirname "$0")"

VENV=${IGS_VENV:-.venv}
# The Python for a new .venv: $PYTHON, else the first that runs of 3.13 (Blender 5.1-5.3's Python,
# with the bpy 5.3 module), 3.11 (Blender 4.2-5.0's, with bpy 5.0.1), 3.14 (no bpy module).
# pyproject.toml's requires-python decides what is allowed (checked in setup).
find_python() {  # $1 = minor version such as 3.13; prints a runnable interpreter or nothing
  local cand=python$1 root v
  # `command -v` alone is not enough: pyenv shims exist for versions that are not selected.
  if command -v "$cand" >/dev/null 2>&1 && "$cand" -c 'import sys' >/dev/null 2>&1; then
    command -v "$cand"; return
  fi
  # Installed through pyenv but not the selected version: take the newest such install directly.
  if command -v pyenv >/dev/null 2>&1; then
    root=$(pyenv root 2>/dev/null) || return 0
    for v in $(pyenv versions --bare 2>/dev/null | grep -E "^$1\.[0-9]+$" | sort -t. -k3 -n -r); do
      if [ -x "$root/versions/$v/bin/$cand" ] && "$root/versions/$v/bin/$cand" -c 'import sys' >/dev/null 2>&1; then
        echo "$root/versions/$v/bin/$cand"; return
      fi
    done
  fi
}
PY=${PYTHON:-}
if [ -z "$PY" ] && [ ! -x "$VENV/bin/python" ]; then
  for minor in 3.13 3.11 3.14; do
    PY=$(find_python "$minor")
    [ -n "$PY" ] && break
  done
fi
[ -n "$PY" ] || PY=$VENV/bin/python
[ -x "$PY" ] || command -v "$PY" >/dev/null 2>&1 || { echo "dev.sh: none of python3.13, python3.11, python3.14 runs here (pyenv installs included); set PYTHON=/path/to/python (3.13 preferred: Blender 5.3's Python, with the bpy module)" >&2; exit 2; }
PY_MINOR=$("$PY" -c 'import sys; print("%d.%d" % sys.version_info[:2])' 2>/dev/null) \
  || { echo "dev.sh: PYTHON=$PY does not run" >&2; exit 2; }
case "$PY_MINOR" in
  3.11|3.13) ;;
  *) [ -x "$VENV/bin/python" ] \
       || echo "dev.sh: using Python $PY_MINOR ($PY): no bpy module for it, so the Blender background tests will skip (set PYTHON=python3.13 to run them)" >&2 ;;
esac
# Optional: where torch alone comes from, e.g. https://download.pytorch.org/whl/cpu for the 192 MB
# CPU-only build (default: the configured index, PyPI, whose Linux torch is the ~2.7 GB CUDA build).
TORCH_INDEX=${IGS_TORCH_INDEX:-}

setup() {
  # Re-install only when the pinned dependencies changed since the last successful install.
  local stamp="$VENV/.igs-installed" want torch
  want=$(sha256sum pyproject.toml | cut -d' ' -f1)
  if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ] && [ -x "$VENV/bin/python" ]; then
    return 0
  fi
  # One line before a first install that cannot fit, instead of pip's "No space left on device" minutes in:
  # a new .venv holds about 7 GB (torch's CUDA build and its libraries, bpy) and pip unpacks the
  # wheels beside it. Set IGS_SETUP_MIN_FREE_GB=0 to skip the check.
  local need_gb=${IGS_SETUP_MIN_FREE_GB:-10} free_gb
  mkdir -p "$(dirname "$VENV")"
  free_gb=$(df -Pk "$(dirname "$VENV")" | awk 'NR==2 {printf "%d", $4 / 1048576}')
  if [ ! -x "$VENV/bin/python" ] && [ -n "$free_gb" ] && [ "$free_gb" -lt "$need_gb" ]; then
    echo "dev.sh: setting up $VENV needs about $need_gb GB free on its disk; $free_gb GB are (free some, or set IGS_SETUP_MIN_FREE_GB)" >&2
    exit 2
  fi
  if [ ! -x "$VENV/bin/python" ]; then
    # One line saying which Pythons requires-python allows, instead of a pip resolver error later.
    "$PY" igs_blender/env/check_env.py --pyproject pyproject.toml --python-only || exit 2
    "$PY" -m venv "$VENV"
  fi
  echo "== setting up $VENV with Python $("$VENV/bin/python" -c 'import sys; print(sys.version.split()[0])') (first run downloads 1-5 GB: torch, bpy, pycolmap, opencv, numba) =="
  # No pip cache: it would keep a second copy of the ~3 GB of wheels on the same disk.
  export PIP_NO_CACHE_DIR=1
  "$VENV/bin/python" -m pip install -q --upgrade pip
  # torch first and on its own (its pin as it applies to this Python), so that the rest cannot
  # pull another build; then the project with the pins pip picks by their python_version markers.
  torch=$("$VENV/bin/python" igs_blender/env/check_env.py --pyproject pyproject.toml --list | grep -E '^torch([=<>!~]|$)') \
    || { echo "dev.sh: pyproject.toml pins no torch for Python $("$VENV/bin/python" -V)" >&2; exit 2; }
  "$VENV/bin/python" -m pip install -q ${TORCH_INDEX:+--index-url "$TORCH_INDEX"} "$torch"
  "$VENV/bin/python" -m pip install -q -e ".[dev]"
  echo "$want" > "$stamp"
}

versions() {
  # One line at the start of each run: what this environment is (the README's figures name it).
  "$VENV/bin/python" - <<'PYEOF'
import importlib.metadata as md, sys
def v(name):
    try:
        return md.version(name)
    except md.PackageNotFoundError:
        return "none"
print(f"== {sys.executable}: Python {sys.version.split()[0]}, torch {v('torch')}, numpy {v('numpy')}, "
      f"bpy {v('bpy')}, pycolmap {v('pycolmap')} ==", flush=True)
PYEOF
}

npm_tools() {
  # PlayCanvas's splat-transform (pinned) for the interop tests, into $VENV/npm-tools, when npm exists;
  # without it (or offline) those tests skip with one line.
  local want=3.7.0 dir="$VENV/npm-tools"
  command -v npm >/dev/null 2>&1 || return 0
  [ "$(cat "$dir/.installed" 2>/dev/null)" = "$want" ] && return 0
  if npm install --silent --no-audit --no-fund --prefix "$dir" "@playcanvas/splat-transform@$want" >/dev/null 2>&1; then
    echo "$want" > "$dir/.installed"
  else
    echo "dev.sh: npm could not install @playcanvas/splat-transform@$want; the interop tests with it will skip" >&2
  fi
}

cmd=${1:-}
[ $# -gt 0 ] && shift
case "$cmd" in
  setup) setup ;;
  demo)  setup; versions; exec "$VENV/bin/igs" demo "$@" ;;
  test)  setup; versions; npm_tools; exec "$VENV/bin/python" -m pytest -q "$@" ;;
  test-py311)
    # The backend suite once more on Python 3.11 (Blender 4.2-5.0's backend environments: bpy 5.0.1,
    # numpy 1.26), in its own .venv-py311. CI runs it after the main suite; the test list is
    # tests/py311_tests.txt (the reason for the choice is at its top).
    py311=${PYTHON311:-$(find_python 3.11)}
    [ -n "$py311" ] || { echo "dev.sh: test-py311 needs Python 3.11 (python3.11 on PATH or through pyenv, or PYTHON311=...)" >&2; exit 2; }
    mapfile -t subset < <(grep -vE '^\s*(#|$)' tests/py311_tests.txt)
    IGS_VENV=${IGS_VENV_311:-.venv-py311} PYTHON=$py311 exec "$0" test "${subset[@]}" "$@" ;;
  test-blender)
    # The add-on in a real Blender 5.2 window (Debian's, in a cached sid root, under Xvfb): needs root.
    setup
    if [ "$(id -u)" = 0 ] && ! command -v debootstrap >/dev/null 2>&1 && command -v apt-get >/dev/null 2>&1; then
      apt-get install -y -qq debootstrap >/dev/null 2>&1 || { apt-get update -qq && apt-get install -y -qq debootstrap >/dev/null; } || true
    fi
    exec "$VENV/bin/python" -m pytest -q -p no:cacheprovider tests_blender "$@" ;;
  lint)  setup; exec "$VENV/bin/ruff" check . ;;
  igs)   setup; exec "$VENV/bin/igs" "$@" ;;
  # gsplat's kernels built without a CUDA toolkit, in a fresh environment (slow; scripts/gsplat_build.sh)
  gsplat-build) PYTHON=${PYTHON:-$(find_python 3.13)} exec scripts/gsplat_build.sh "$@" ;;
  *) echo "usage: ./dev.sh demo|test|test-blender|test-py311|gsplat-build|setup|lint|igs ARGS..." >&2; exit 2 ;;
esac
