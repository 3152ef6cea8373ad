#!/usr/bin/env bash
# Builds OpenSplat's CPU-only binary for the side-by-side training benchmark
# (python -m backend.bench.bench_train --opensplat BUILD/opensplat), against this project's own
# torch (the pip wheel's libtorch) and Debian's OpenCV (apt-get install cmake g++ libopencv-dev).
#   scripts/build_opensplat.sh SRC BUILD
# SRC is a checkout of https://github.com/pierotofy/OpenSplat. OpenSplat's CMake downloads
# nlohmann_json 3.11.3, nanoflann 1.5.5 and cxxopts 3.2.0; on a machine without GitHub, set
# IGS_OPENSPLAT_DEPS to a folder holding their sources as json/, nanoflann/ and cxxopts/.
set -euo pipefail

SRC=${1:?usage: scripts/build_opensplat.sh SRC BUILD}
BUILD=${2:?usage: scripts/build_opensplat.sh SRC BUILD}
HERE=$(cd "$(dirname "$0")/.." && pwd)
PY=${PYTHON:-$HERE/.venv/bin/python}

[ -f "$SRC/opensplat.cpp" ] || { echo "build_opensplat.sh: $SRC is not an OpenSplat checkout (no opensplat.cpp)" >&2; exit 2; }
[ -x "$PY" ] || { echo "build_opensplat.sh: no Python at $PY (run ./dev.sh setup, or set PYTHON)" >&2; exit 2; }
TORCH_CMAKE=$("$PY" -c "import torch; print(torch.utils.cmake_prefix_path)") \
  || { echo "build_opensplat.sh: $PY cannot import torch" >&2; exit 2; }

deps=()
if [ -n "${IGS_OPENSPLAT_DEPS:-}" ]; then
  for pair in NLOHMANN_JSON:json NANOFLANN:nanoflann CXXOPTS:cxxopts; do
    dir="$IGS_OPENSPLAT_DEPS/${pair#*:}"
    [ -f "$dir/CMakeLists.txt" ] || { echo "build_opensplat.sh: $dir holds no CMakeLists.txt" >&2; exit 2; }
    deps+=("-DFETCHCONTENT_SOURCE_DIR_${pair%%:*}=$dir")
  done
fi

# GPU_RUNTIME=CPU: the CPU rasterizer only, the one `opensplat --cpu` runs.
cmake -S "$SRC" -B "$BUILD" -DCMAKE_BUILD_TYPE=Release -DGPU_RUNTIME=CPU \
  -DCMAKE_PREFIX_PATH="$TORCH_CMAKE" "${deps[@]}"
cmake --build "$BUILD" --target opensplat -j "$(nproc)"
echo "$BUILD/opensplat"
