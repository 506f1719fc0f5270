#!/bin/bash
# The CUDA checks in one run, for a machine with a CUDA device (README, "GPU"): the gpu-marked tests,
# then the maps bench with the Gaussian layer on the CPU and on CUDA (ratio), then both map modes on CUDA.
# Needs only torch, numpy, scipy, opencv, pyyaml and tqdm there (no simulator): it replays a recording
# made on any machine by `python -m tools bench maps` (runs/bench_maps/, carried along). Logs go to $OUT.
#   PYTHON=.venv/bin/python OUT=runs/gpu_checks bash tools/gpu_checks.sh
set -o pipefail
PY=${PYTHON:-python3}
export PYTHONUNBUFFERED=1 PYTHONDONTWRITEBYTECODE=1
OUT=${OUT:-runs/gpu_checks}; mkdir -p "$OUT"
REC=${HELIOS_MAPS_RECORDING:-runs/bench_maps/sim_helios_val0_300f_320x240.npz}
[ -f "$REC" ] || { echo "gpu_checks: no maps recording at $REC: run 'python -m tools bench maps' once first" >&2; exit 2; }
{ nvidia-smi -L; nproc; $PY --version
  $PY -c "import torch, cv2, scipy, yaml, tqdm; print('torch', torch.__version__, 'cuda', torch.cuda.is_available())"
} 2>&1 | tee "$OUT"/env.txt || exit 1
$PY -c "import torch, sys; sys.exit(0 if torch.cuda.is_available() else 1)" ||
  { echo "gpu_checks: torch sees no CUDA device here; nothing to check" >&2; exit 2; }
failed=""   # every step runs; the exit status says whether any failed (or ran past its time limit: 124)
step() {    # step NAME SECONDS COMMAND...: log to $OUT/NAME.txt, remember a failure
  local name=$1 limit=$2; shift 2
  timeout "$limit" "$@" 2>&1 | tee "$OUT/$name.txt" || failed="$failed $name"
}
step gpu_tests 120 $PY -m pytest -m gpu tests/test_maps_gpu.py -p no:cacheprovider -q -rA
step bench_both 240 $PY -m tools bench maps --maps-device both --maps-recording "$REC"
step bench_cuda 150 $PY -m tools bench maps --maps-device cuda --maps-recording "$REC"
echo "gpu_checks: logs in $OUT"
[ -z "$failed" ] || { echo "gpu_checks: failed:$failed" >&2; exit 1; }
