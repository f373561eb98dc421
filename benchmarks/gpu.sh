#!/usr/bin/env bash
# One command on a CUDA GPU machine: install amorctl's jax-mjx stack, check that JAX sees the GPU,
# then print jax-mjx env steps/s and training steps/s for biped20 and humanoid36.
#
#   bash benchmarks/gpu.sh                 # from the repository root; makes .venv-gpu (needs PyPI)
#   ENVS="4096 8192 16384" CHARACTERS="biped20" bash benchmarks/gpu.sh
#   VENV=/path/to/env PYTHON=python3.11 bash benchmarks/gpu.sh
#
# Offline, on a machine whose python3 already has JAX with CUDA (a vendor image): fetch the
# wheels JAX does not bring where PyPI is reachable (the machine's Python version; 3.12 here),
#
#   python3 -m pip download --no-deps --only-binary=:all: --python-version 3.12 \
#       --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 \
#       --platform manylinux_2_17_x86_64 -d .whl mujoco==4.0.1 mujoco-core==4.0.1 \
#       mujoco-mjx==3.17.0 mcap==1.6.0 tomlkit==0.15.3 trimesh==5.2.0 glfw zstandard cffi pycparser
#
# copy .whl to the GPU machine beside the repository, and run `WHEELS=.whl bash benchmarks/gpu.sh`:
# the wheels go into /tmp/site (on PYTHONPATH), amorctl is installed without dependencies, and the
# image's JAX, flax, optax, numpy, scipy and torch are used as they are (docs/backends.md,
# "GPU figures": the versions that ran).
#
# Target: >= 150k env steps/s for biped20 training on one H100/H200-class GPU.
# Results go into docs/backends.md ("GPU figures"), with the GPU model and the JAX version.
set -euo pipefail
cd "$(dirname "$0")/.."
ENVS=${ENVS:-"4096 16384"}
CHARACTERS=${CHARACTERS:-"biped20 humanoid36"}
VENV=${VENV:-.venv-gpu}
PYTHON=${PYTHON:-python3}
WHEELS=${WHEELS:-}

command -v nvidia-smi >/dev/null && nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv
if [ -n "$WHEELS" ]; then
    "$PYTHON" -m pip install -q --no-index --no-deps --no-compile --upgrade --target /tmp/site "$WHEELS"/*.whl
    export PYTHONPATH=/tmp/site${PYTHONPATH:+:$PYTHONPATH}
    "$PYTHON" -m pip install -q --no-index --no-deps --no-build-isolation -e .
    PY=$PYTHON
else
    if [ ! -x "$VENV/bin/python" ]; then
        "$PYTHON" -m venv "$VENV"
    fi
    "$VENV/bin/python" -m pip install -q --upgrade pip
    "$VENV/bin/python" -m pip install -q -e ".[jax-cuda]"
    PY=$VENV/bin/python
fi
"$PY" - <<'PY'
import flax
import jax
import mujoco
import optax

gpus = [d for d in jax.devices() if d.platform == "gpu"]
print("jax", jax.__version__, "flax", flax.__version__, "optax", optax.__version__,
      "mujoco", mujoco.__version__, "devices:", jax.devices())
if not gpus:
    raise SystemExit("no GPU visible to JAX: check the NVIDIA driver and the jax[cuda12] install")
PY
export PYTHONUNBUFFERED=1
# shellcheck disable=SC2086
"$PY" benchmarks/backend_throughput.py --skip-torch --train --jax-steps 50 --iterations 5 \
    --characters $CHARACTERS --envs $ENVS --timeout 400
