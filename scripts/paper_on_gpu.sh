#!/usr/bin/env bash
# The paper-scale run (experiment=paper) on a CUDA machine that has Python and torch but no DVC
# and cannot install this package (another Python or torch than pyproject.toml pins), e.g. a
# borrowed GPU box. On a machine where the package installs, use the normal route instead:
#   cmal-lcd compose-params experiment=paper && dvc repro
#
#   scripts/paper_on_gpu.sh OUT [HYDRA_OVERRIDE...]
#
# What it does, all logged to OUT/run.log:
#  1. installs the pure-Python wheels in .whl/ (hydra-core, omegaconf, antlr4, the EfficientNet
#     packages) into /tmp/site when that folder exists, and runs from src/;
#  2. records the device (OUT/device.txt) and checks the CPU kernel pin on this processor
#     (tests/test_kernels.py with the GPU hidden; OUT/kernels.txt);
#  3. measures seconds per training iteration of CMAL and BiGAN at the paper's widths on the GPU
#     (benchmarks/bench_training.py; OUT/bench_training.txt);
#  4. runs the whole chain with the Hydra app (cmal_lcd.app: the stage functions of dvc.yaml, in
#     its order) on experiment=paper, runtime.threads=$(nproc), into RUN_DIR (default
#     /tmp/paper_run), stopped after RUN_LIMIT_S seconds (default 540); ITERATIONS, when set,
#     overrides both models' iterations;
#  5. packs reports/, metrics.json, the composed config, the training logs and the per-method
#     evaluation summaries (no feature arrays, matrices or weights) into OUT/paper_run.tar.gz.
set -uo pipefail

out=${1:?usage: scripts/paper_on_gpu.sh OUT [HYDRA_OVERRIDE...]}
shift
mkdir -p "$out"
out=$(cd "$out" && pwd)
exec > >(tee -a "$out/run.log") 2>&1
run_dir=${RUN_DIR:-/tmp/paper_run}
limit=${RUN_LIMIT_S:-540}
threads=${THREADS:-$(nproc)}
start=$(date +%s)
stamp() { echo "[$(( $(date +%s) - start )) s] $*"; }

export PYTHONUNBUFFERED=1
if [ -d .whl ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
    --target /tmp/site .whl/*.whl || { echo "wheel install failed"; exit 1; }
  export PYTHONPATH="/tmp/site:$PWD/src"
else
  export PYTHONPATH="$PWD/src${PYTHONPATH:+:$PYTHONPATH}"
fi

stamp "device"
{
  date -u
  nvidia-smi -L 2>&1 || true
  python3 -c 'import torch, numpy, platform; print("python", platform.python_version(),
"torch", torch.__version__, "cuda", torch.version.cuda, "numpy", numpy.__version__);
print("gpu", torch.cuda.get_device_name() if torch.cuda.is_available() else "none");
print("cpu capability", torch.backends.cpu.get_cpu_capability())'
  grep -m1 "model name" /proc/cpuinfo
  echo "nproc $(nproc)"
} > "$out/device.txt" 2>&1
cat "$out/device.txt"

stamp "kernel pin on this CPU (GPU hidden)"
CUDA_VISIBLE_DEVICES= timeout 180 python3 -m pytest -q -p no:cacheprovider tests/test_kernels.py \
  > "$out/kernels.txt" 2>&1
tail -n 3 "$out/kernels.txt"

stamp "training speed at the paper's widths"
timeout 180 python3 benchmarks/bench_training.py --device "${BENCH_DEVICE:-cuda}" --threads "$threads" --steps 30 \
  --overrides experiment=paper > "$out/bench_training.txt" 2>&1
cat "$out/bench_training.txt"

iterations=()
if [ -n "${ITERATIONS:-}" ]; then
  iterations=(models.cmal.iterations="$ITERATIONS" models.bigan.iterations="$ITERATIONS")
fi

stamp "the chain: experiment=paper"
rm -rf "$run_dir"
timeout "$limit" python3 -m cmal_lcd.app experiment=paper runtime.threads="$threads" \
  "${iterations[@]}" hydra.run.dir="$run_dir" "$@"
status=$?
stamp "the chain exited with $status"

cd "$run_dir" 2>/dev/null || { echo "no run folder $run_dir"; exit 1; }
tar czf "$out/paper_run.tar.gz" --exclude='*.npy' --exclude='*.npz' --exclude='*.pt' \
  --exclude='data/features' --exclude='data/dataset/images*' --exclude='checkpoints' \
  reports metrics.json .hydra models data/protocol data/evaluation data/dataset/dataset.json \
  data/manifest.csv 2>/dev/null
ls -la "$out"
stamp "done"
exit $status
