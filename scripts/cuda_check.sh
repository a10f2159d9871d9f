#!/usr/bin/env bash
# The CUDA check, in one run of at most 8 minutes: install the package on a CUDA machine, run the CUDA tests
# (compiled-vs-eager TOPO update with CUDA graphs; a model trained and saved on CUDA, loaded on the CPU) and the
# planner and training benchmarks on CUDA.
#
# The device machines have PyTorch with CUDA but no network: first, here, download what the package needs besides
# torch into .wheels/ (git-ignored), then run this script there with .wheels carried:
#     bash scripts/cuda_check.sh --prepare
#     device run: bash scripts/cuda_check.sh        (carry: [".wheels"]; results in $OUT when set)
set -euo pipefail
cd "$(dirname "$0")/.."
PACKAGES=(stable-baselines3 sb3-contrib gymnasium farama-notifications mujoco mujoco-core mujoco-studio glfw pyopengl websockets)

if [ "${1:-}" = "--prepare" ]; then
  rm -rf .wheels && mkdir -p .wheels
  pip download --no-deps --only-binary=:all: --python-version 3.12 --platform manylinux2014_x86_64 \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 -d .wheels "${PACKAGES[@]}"
  du -sh .wheels
  exit 0
fi

out="${OUT:-/tmp/cuda_check}"
mkdir -p "$out"
python3 -c "import torch; assert torch.cuda.is_available(), 'no CUDA device'; print(torch.__version__, torch.cuda.get_device_name())"
python3 -m pip install -q --no-index --no-deps .wheels/*.whl
python3 -m pip install -q --no-index --no-deps --no-build-isolation -e .
export PYTHONUNBUFFERED=1
timeout 180 python3 -m pytest -q -p no:cacheprovider -m cuda tests/sppo/test_compile.py 2>&1 | tee "$out/cuda_tests.txt"
timeout 150 python3 scripts/bench_planner.py --quick --devices cuda --sizes td-mpc --json "$out/planner.json" 2>&1 | grep -v '^W' | tee "$out/planner.txt"
timeout 150 python3 scripts/bench_training.py --device cuda --envs HalfCheetah-v5 SafePointCircle-v0 --steps 500 2>&1 \
  | grep -v '^W' | tee "$out/training.txt"
