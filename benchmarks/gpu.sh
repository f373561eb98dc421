#!/usr/bin/env bash
# One command on a CUDA GPU machine: install amorctl with the `jax-cuda` extra (jax-mjx + JAX's
# CUDA 12 wheels; only the NVIDIA driver is needed), check that JAX sees the GPU, then print
# jax-mjx env steps/s and training steps/s at 4096-16384 envs for biped20 and humanoid36.
#
#   bash benchmarks/gpu.sh                 # from the repository root; makes .venv-gpu
#   ENVS="4096 8192 16384" CHARACTERS="biped20" bash benchmarks/gpu.sh
#   VENV=/path/to/env PYTHON=python3.11 bash benchmarks/gpu.sh
#
# Target: >= 150k env steps/s for biped20 training on one H100/H200-class GPU.
# Results go into docs/backends.md ("GPU figures"), with the GPU model and the JAX version.
set -euo pipefail
cd "$(dirname "$0")/.."
ENVS=${ENVS:-"4096 8192 16384"}
CHARACTERS=${CHARACTERS:-"biped20 humanoid36"}
VENV=${VENV:-.venv-gpu}
PYTHON=${PYTHON:-python3}

command -v nvidia-smi >/dev/null && nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv
if [ ! -x "$VENV/bin/python" ]; then
    "$PYTHON" -m venv "$VENV"
fi
"$VENV/bin/python" -m pip install -q --upgrade pip
"$VENV/bin/python" -m pip install -q -e ".[jax-cuda]"
"$VENV/bin/python" - <<'PY'
import jax
gpus = [d for d in jax.devices() if d.platform == "gpu"]
print("jax", jax.__version__, "devices:", jax.devices())
if not gpus:
    raise SystemExit("no GPU visible to JAX: check the NVIDIA driver and the jax[cuda12] install")
PY
# shellcheck disable=SC2086
"$VENV/bin/python" benchmarks/backend_throughput.py --skip-torch --train --jax-steps 50 --iterations 5 \
    --characters $CHARACTERS --envs $ENVS
