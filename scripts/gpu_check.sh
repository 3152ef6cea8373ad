#!/usr/bin/env bash
# The prepared run for a lent GPU machine (docs/testing.md, "On a lent GPU"), in one call:
#   1. the environment: python, torch, CUDA, gsplat; wheels in .whl/ are installed first
#      (pycolmap, plyfile and gsplat: the machine has no package index);
#   2. a workspace from the tests' box scene at the demo's size (96 views at 256x192, 100k
#      Gaussians and as many SfM points), made there, since a rendered capture is too large to
#      travel (12 s on 2 cores);
#   3. bench_step on it: each stage's iteration by phase, GPU busy time, host-device syncs, memory,
#      beside gsplat's own trainer step on the same views (the gsplat row; CUDA only). The schedule
#      is the paper's (30k iterations), so neither densifies before step 500: in the window both
#      train the same 100k Gaussians. gsplat compiles its kernels on its first call here, about 100 s;
#   4. the CUDA tests (with the kernels already built).
# Everything lands in $OUT (default /tmp/gpu_check): log.txt, env.txt, bench_step.json. The
# measurement comes before the tests, and the limits (40 + 20 + 40 + 330 + 160 s) add up to less than
# the 600 s a device command may run: if the tests are cut short, the JSON is already there.
#   scripts/gpu_check.sh              # on the GPU machine, from the repository root
#   DEVICE=cpu BACKEND=cpu STAGES=3dgs,albedo,shading,residual VIEWS=8 SIZE=64x48 POINTS=1000 WARMUP=5 \
#     STEPS=5 scripts/gpu_check.sh   # a dry run here (the gsplat row needs CUDA)
# Each step has its own time limit, and a failed step does not stop the next.
set -u
cd "$(dirname "$0")/.."
OUT=${OUT:-/tmp/gpu_check}
PY=${PYTHON:-python3}
DEVICE=${DEVICE:-cuda}
BACKEND=${BACKEND:-gsplat}
VIEWS=${VIEWS:-96}
SIZE=${SIZE:-256x192}
WARMUP=${WARMUP:-300}
STEPS=${STEPS:-100}
POINTS=${POINTS:-100000}
ITERATIONS=${ITERATIONS:-30000}
WS=${WS:-/tmp/gpu_check_ws}
STAGES=${STAGES:-3dgs,gsplat,albedo,shading,residual}
mkdir -p "$OUT"
exec > >(tee -a "$OUT/log.txt") 2>&1
step() { echo; echo "== $(date -u +%H:%M:%S) $*"; }

step "1. environment"
if compgen -G ".whl/*.whl" >/dev/null; then
  timeout 40 "$PY" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/igs_site .whl/*.whl \
    && export PYTHONPATH=/tmp/igs_site:${PYTHONPATH:-}
fi
export PYTHONPATH=$PWD:${PYTHONPATH:-}
timeout 20 "$PY" - <<'EOF' | tee "$OUT/env.txt"
import platform, torch
print("python", platform.python_version(), "torch", torch.__version__, "cuda", torch.version.cuda)
print("device", torch.cuda.get_device_name(0) if torch.cuda.is_available() else "none")
for name in ("gsplat", "pycolmap", "plyfile", "numba", "cv2", "scipy"):
    try:
        print(name, getattr(__import__(name), "__version__", "?"))
    except Exception as e:  # noqa: BLE001  (a report, not a program)
        print(name, "MISSING:", e)
# Whether this Python already has NVIDIA's compiler wheels: the set-up's toolkit-free gsplat build
# (igs_blender/env/cuda_build.py) needs them, and at ~100 MB they cannot travel in .whl/.
import importlib.metadata as md, shutil
for dist in ("nvidia-cuda-nvcc", "nvidia-nvvm", "nvidia-cuda-cccl", "cuda-toolkit"):
    try:
        print(dist, md.version(dist))
    except md.PackageNotFoundError:
        print(dist, "MISSING")
print("system nvcc", shutil.which("nvcc") or "none")
EOF

step "2. the box workspace: $VIEWS views at $SIZE, $POINTS points, in $WS"
rm -rf "$WS"
timeout 40 "$PY" - "$WS" "$VIEWS" "${SIZE%x*}" "${SIZE#*x}" "$POINTS" <<'EOF'
import shutil, sys
from pathlib import Path
from tests.support.train_scene import make_workspace  # the tests' box scene: rendered here, nothing to carry
root, views, w, h, points = Path(sys.argv[1]), *map(int, sys.argv[2:])
make_workspace(root, n_views=views, width=w, height=h, n_points=points, n_per_face=-(-points // 5))
shutil.copytree(root / "images", root / "albedo")  # the images stand in for the albedo priors
print("workspace", root, views, "views", w, "x", h)
EOF

step "3. bench_step on $DEVICE ($BACKEND), warm-up $WARMUP, $STEPS profiled, a $ITERATIONS-iteration schedule"
timeout 330 "$PY" -m backend.bench.bench_step "$WS" --device "$DEVICE" --backend "$BACKEND" --stages "$STAGES" \
  --warmup "$WARMUP" --steps "$STEPS" --iterations "$ITERATIONS" --out "$OUT/bench_step.json"
if [ "$DEVICE" != cpu ]; then
  step "4. the CUDA tests"
  timeout 160 "$PY" -m pytest -q -p no:cacheprovider tests/backend/render/test_render_gsplat.py tests/backend/train/test_train_cuda.py
fi

step "done"
