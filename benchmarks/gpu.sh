#!/usr/bin/env bash
# One command on a CUDA GPU machine: install the jax extra with JAX's CUDA 12 plugin, check that JAX
# sees the GPU, then print jax-mjx env steps/s and training steps/s at 4096-16384 envs.
#
#   bash benchmarks/gpu.sh                 # from the repository root, in a fresh virtualenv
#   ENVS="4096 8192 16384" CHARACTERS="biped20" bash benchmarks/gpu.sh
#
# Target (issue 14): >= 150k env steps/s for biped20 training on one H100/H200-class GPU.
# Results go into docs/backends.md ("GPU figures").
set -euo pipefail
cd "$(dirname "$0")/.."
ENVS=${ENVS:-"4096 8192 16384"}
CHARACTERS=${CHARACTERS:-"biped20 humanoid36"}

python -m pip install -q -e ".[jax]" "jax[cuda12]>=0.10,<0.11"
python - <<'EOF'
import jax
gpus = [d for d in jax.devices() if d.platform == "gpu"]
print("jax", jax.__version__, "devices:", jax.devices())
if not gpus:
    raise SystemExit("no GPU visible to JAX: check the NVIDIA driver and the jax[cuda12] install")
EOF
# shellcheck disable=SC2086
python benchmarks/backend_throughput.py --skip-torch --train --steps 50 --iterations 5 \
    --characters $CHARACTERS --envs $ENVS
