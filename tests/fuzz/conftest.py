"""Valid seed files of every input class, built once per session in seconds (no network, no data)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from amorctl.motion.source import CANONICAL_JOINTS

BIPED20_JOINTS = (
    "head_pan", "head_tilt", "l_sho_pitch", "l_sho_roll", "l_el", "r_sho_pitch", "r_sho_roll", "r_el",
    "l_hip_yaw", "l_hip_roll", "l_hip_pitch", "l_knee", "l_ank_pitch", "l_ank_roll", "r_hip_yaw",
    "r_hip_roll", "r_hip_pitch", "r_knee", "r_ank_pitch", "r_ank_roll",
)  # fmt: skip
FRAMES = 6

TOY_TOML = """
[run]
iterations = 2
checkpoint_every = 2
keep_checkpoints = 0
tensorboard = false
threads = 1
[env]
kind = "toy"
num_envs = 16
episode_seconds = 0.3
[network]
actor_hidden = [8]
critic_hidden = [8]
[ppo]
precision = "fp32"
num_steps = 4
num_epochs = 1
num_minibatches = 1
"""


def deepmimic_doc() -> dict:
    """A 6-frame DeepMimic clip at 30 Hz: walking forward, knees bending a little."""
    rows = []
    for t in range(FRAMES):
        row = [1 / 30, 0.05 * t, 0.9, 0.0, 1.0, 0.0, 0.0, 0.0]
        for width in (4, 4, 4, 1, 4, 4, 1, 4, 1, 4, 4, 1):
            row += [1.0, 0.0, 0.0, 0.0] if width == 4 else [0.1 * t]
        rows.append(row)
    return {"Loop": "wrap", "Frames": rows}


def bvh_text() -> str:
    """A 6-frame BVH on the canonical joint names (all chained under the root), 30 Hz."""
    lines = [
        "HIERARCHY",
        "ROOT root",
        "{",
        "OFFSET 0 0 0",
        "CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation",
    ]
    for j in CANONICAL_JOINTS[1:]:
        lines += [f"JOINT {j}", "{", "OFFSET 0 0.1 0", "CHANNELS 3 Zrotation Xrotation Yrotation", "}"]
    lines += ["}", "MOTION", f"Frames: {FRAMES}", "Frame Time: 0.033333"]
    for t in range(FRAMES):
        lines.append(" ".join([f"{0.05 * t:g} 0.9 0", "0 0 0"] + [f"{2 * t} 0 0"] * 12))
    return "\n".join(lines) + "\n"


BVH_MAP = "[joints]\n" + "".join(f'{j} = "{j}"\n' for j in CANONICAL_JOINTS)


def npz_arrays() -> dict[str, np.ndarray]:
    """A 6-frame biped20 robot motion in the mjlab layout."""
    quat = np.zeros((FRAMES, 1, 4))
    quat[..., 0] = 1
    pos = np.zeros((FRAMES, 1, 3))
    pos[:, 0, 0] = 0.02 * np.arange(FRAMES)
    pos[:, 0, 2] = 0.3
    return {
        "fps": np.array(50.0),
        "joint_pos": 0.01 * np.arange(FRAMES * 20, dtype=np.float64).reshape(FRAMES, 20),
        "joint_vel": np.zeros((FRAMES, 20)),
        "body_pos_w": pos,
        "body_quat_w": quat,
        "joint_names": np.array(BIPED20_JOINTS),
        "body_names": np.array(["torso"]),
    }


@pytest.fixture(scope="session")
def seed_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A two-clip biped20 dataset (synthetic motion) with an encoder attachment."""
    import dataclasses

    from safetensors.numpy import save

    from amorctl.envs.synthetic import synthetic_library
    from amorctl.motion.dataset import write_dataset
    from amorctl.registry import get_registry

    lib = synthetic_library(get_registry().character("biped20"), num_clips=2, seconds=0.2, seed=1)
    clips = tuple(dataclasses.replace(c, name=n) for c, n in zip(lib.clips, ("a", "b"), strict=True))
    path = tmp_path_factory.mktemp("fuzz-dataset") / "seed.mcap"
    encoder = save({"w": np.ones((2, 2), dtype=np.float32)}, metadata={"format": "fuzz"})
    write_dataset(path, dataclasses.replace(lib, clips=clips), encoder=encoder)
    return path


@pytest.fixture(scope="session")
def seed_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A two-iteration toy run (MOPPO, objectives right / left) with one checkpoint."""
    import torch

    from amorctl.cli.main import main

    root = tmp_path_factory.mktemp("fuzz-run")
    (root / "toy.toml").write_text(TOY_TOML)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        assert main(["train", "--config", str(root / "toy.toml"), "--out", str(root / "run"), "--json"]) == 0
    finally:
        torch.set_num_threads(threads)
    return root / "run"


@pytest.fixture(scope="session")
def seed_deepmimic() -> str:
    return json.dumps(deepmimic_doc())
