#!/usr/bin/env bash
# `./dev.sh gsplat-build`: the NVIDIA CUDA set-up's compiler path, proved from nothing (docs/testing.md).
#   ./dev.sh gsplat-build [--archs "8.0;8.9;9.0"] [--dir build/gsplat-build] [--if-changed] [--keep-wheels]
# 1. A fresh environment in DIR/env (DIR is replaced) with $PYTHON (dev.sh's choice), and torch's
#    CUDA build from PyPI at the pin of pyproject.toml.
# 2. igs_blender/env/cuda_build.py, the code the add-on's set-up runs: NVIDIA's compiler wheels for torch's
#    CUDA release, gsplat's kernels built from its sdist for ARCHS where no GPU is visible (the GPU
#    here otherwise), the module imported through gsplat's own import and its architectures read back.
# Every package is downloaded into DIR/wheels first (from PyPI alone: pip --isolated), so that the
# download is measured; the installs read only that folder. A system CUDA toolkit (nvcc on PATH,
# /usr/local/cuda*) is hidden from the whole run when a private mount namespace can be made (root and
# unshare): an empty tmpfs over each /usr/local/cuda* folder, /dev/null over each nvcc on PATH.
# Elsewhere it stays visible, and unused: the build's CUDA_HOME is the environment's own.
# --if-changed: skip (printing the last result) when a build of the same inputs already succeeded here
# (the stamp is in ${XDG_CACHE_HOME:-~/.cache}/intrinsic-splats/); CI runs it that way.
# Prints one result line: architectures, time, downloads, disk.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
DIR=build/gsplat-build
ARCHS="8.0;8.9;9.0"
IF_CHANGED=0
KEEP_WHEELS=0
while [ $# -gt 0 ]; do
  case "$1" in
    --archs) ARCHS=${2:?--archs needs a list such as "8.0;8.9;9.0"}; shift 2 ;;
    --dir) DIR=${2:?--dir needs a folder}; shift 2 ;;
    --if-changed) IF_CHANGED=1; shift ;;
    --keep-wheels) KEEP_WHEELS=1; shift ;;
    *) echo "gsplat-build: unknown option '$1' (expected --archs LIST, --dir DIR, --if-changed, --keep-wheels)" >&2; exit 2 ;;
  esac
done

STAMP_DIR=${XDG_CACHE_HOME:-$HOME/.cache}/intrinsic-splats
STAMP=$STAMP_DIR/gsplat-build.stamp
inputs=$( { cat igs_blender/env/cuda_build.py igs_blender/env/check_env.py scripts/gsplat_build.sh pyproject.toml;
            echo "$ARCHS"; "$PY" -V; } | sha256sum | cut -d' ' -f1)
if [ "$IF_CHANGED" = 1 ] && [ "$(head -1 "$STAMP" 2>/dev/null)" = "$inputs" ]; then
  echo "gsplat-build: inputs unchanged since the last successful build; its result: $(tail -1 "$STAMP")"
  exit 0
fi

# Hide a system toolkit: re-run this script in a private mount namespace that covers it.
visible() { ls -d /usr/local/cuda* 2>/dev/null; which -a nvcc 2>/dev/null || true; }
if [ -z "${IGS_GSPLAT_NS:-}" ] && [ -n "$(visible)" ] && [ "$(id -u)" = 0 ] && unshare -m true 2>/dev/null; then
  exec unshare -m --propagation private env IGS_GSPLAT_NS=1 bash "$0" --archs "$ARCHS" --dir "$DIR" \
    $([ "$KEEP_WHEELS" = 1 ] && echo --keep-wheels)
fi
hidden=""
if [ -n "${IGS_GSPLAT_NS:-}" ]; then
  for d in $(ls -d /usr/local/cuda* 2>/dev/null); do
    [ -L "$d" ] || { mount -t tmpfs -o size=1m,mode=0755 igs-hide "$d"; hidden="$hidden $d"; }
  done
  for n in $(which -a nvcc 2>/dev/null || true); do mount --bind /dev/null "$n"; hidden="$hidden $n"; done
fi
if which nvcc >/dev/null 2>&1 || [ -e /usr/local/cuda/bin/nvcc ]; then
  toolkit="a system CUDA toolkit is visible ($(which nvcc || echo /usr/local/cuda)) but not used: the build's CUDA_HOME is the environment's"
elif [ -n "$hidden" ]; then
  toolkit="no CUDA toolkit visible (hidden for this run:$hidden)"
else
  toolkit="no CUDA toolkit on this machine"
fi
echo "gsplat-build: $toolkit"

secs() { date +%s; }
gb() { awk -v b="$1" 'BEGIN { printf (b >= 1e9 ? "%.2f GB" : "%.0f MB"), (b >= 1e9 ? b / 1e9 : b / 1e6) }'; }
t0=$(secs)
rm -rf "$DIR"
mkdir -p "$DIR/wheels"
W=$(cd "$DIR/wheels" && pwd)
"$PY" -m venv "$DIR/env"
E=$(cd "$DIR/env" && pwd)/bin/python
PIP=("$E" -m pip --isolated --disable-pip-version-check)
torch=$("$E" igs_blender/env/check_env.py --pyproject pyproject.toml --list | grep -E '^torch==') \
  || { echo "gsplat-build: pyproject.toml pins no torch for $("$E" -V)" >&2; exit 2; }
echo "== downloading $torch (torch's CUDA build and NVIDIA's CUDA libraries) into $W"
"${PIP[@]}" download -q --no-cache-dir -d "$W" "$torch"
"${PIP[@]}" install -q --no-index --find-links "$W" "$torch"
t_torch=$(secs)
mapfile -t compiler < <("$E" igs_blender/env/cuda_build.py --python "$E" --print-requirements)
echo "== downloading NVIDIA's compiler and gsplat's undeclared dependency (${compiler[*]}), gsplat's sdist and its dependencies"
"${PIP[@]}" download -q --no-cache-dir -d "$W" "${compiler[@]}"
compiler_bytes=$(du -cb "$W"/nvidia_cuda_nvcc-* "$W"/nvidia_cuda_crt-* "$W"/nvidia_nvvm-* "$W"/nvidia_cuda_cccl-* \
  "$W"/cuda_toolkit-* "$W"/ninja-* | tail -1 | cut -f1)
# Reading the sdist's metadata runs its setup.py, which asks torch for CUDA_HOME: the compiler's future place.
# gsplat asks for any torch, and pip download ignores the installed one: the pin keeps it at ours.
home=$("$E" -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')/nvidia/cu13
CUDA_HOME=$home "${PIP[@]}" download -q --no-cache-dir --no-build-isolation --no-binary gsplat -d "$W" "$torch" \
  "$("$E" -c 'import sys; sys.path.insert(0, "igs_blender/env"); import cuda_build; print(cuda_build.GSPLAT)')"
if [ "$(ls "$W"/torch-* | wc -l)" != 1 ]; then echo "gsplat-build: more than one torch downloaded: $(ls "$W"/torch-*)" >&2; exit 2; fi
download_bytes=$(du -sb "$W" | cut -f1)
env_before=$(du -sb "$DIR/env" | cut -f1)
echo "== cuda_build.py: the compiler, then gsplat's kernels for $ARCHS"
"$E" igs_blender/env/cuda_build.py --python "$E" --cuda-archs "$ARCHS" --pip-arg=--isolated \
  --pip-arg=--no-index --pip-arg="--find-links=$W" | tee "$DIR/cuda_build.out"
summary=$(tail -1 "$DIR/cuda_build.out")
t_end=$(secs)
env_after=$(du -sb "$DIR/env" | cut -f1)
built=$("$E" -c 'import json, sys; s = json.loads(sys.argv[1]); print(", ".join("sm_%d" % v for v in s["sm"]) + (" (+PTX %s)" % ", ".join("compute_%d" % v for v in s["ptx"]) if s["ptx"] else "")); print(s["build_seconds"], s["jobs"], s["module"])' "$summary")
{ read -r archs_text; read -r build_s jobs module; } <<< "$built"
[ "$KEEP_WHEELS" = 1 ] || rm -rf "$W"
mins() { awk -v s="$1" 'BEGIN { printf "%d min %02d s", s / 60, s % 60 }'; }
result="gsplat $("$E" -c 'import importlib.metadata as m; print(m.version("gsplat"))') built for $archs_text and imported (gsplat.cuda._backend._C = $module) in $(mins $((t_end - t0))) on $(nproc) CPUs: torch $(mins $((t_torch - t0))), kernels $(mins "${build_s%.*}") with $jobs parallel compiles, the rest $(mins $((t_end - t0 - (t_torch - t0) - ${build_s%.*}))); downloads $(gb "$download_bytes") (NVIDIA's compiler $(gb "$compiler_bytes")); environment $(gb "$env_after") on disk ($(gb $((env_after - env_before))) of it the compiler, gsplat and its dependencies); $toolkit"
echo "gsplat-build: $result"
mkdir -p "$STAMP_DIR"
printf '%s\n%s\n' "$inputs" "$(date -u +%Y-%m-%d) $result" > "$STAMP"
