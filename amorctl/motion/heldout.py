"""Try a trained run on other clips: ``--data DATASET`` of ``evaluate``, ``pareto`` and ``tune``.

A policy reads the motion context z_t of its own training dataset's VAE. Clips preprocessed
elsewhere carry another VAE's latents (or none), so :func:`dataset_for_run` re-encodes their
frames with the run dataset's encoder and writes the result once to the user cache (a run
dataset without an encoder, preprocessed with ``--no-vae``, needs latents of the same size and
uses the file as it is); the run's
env is then rebuilt on that file (:meth:`amorctl.train.rundir.RunDir.config_for_data`, which first
tells a moved copy of the run's own dataset, by its SHA-256, from held-out clips). The character, joint order,
end effectors, frame rate and frame layout must match the run's: a mismatch is refused naming
both files and what differs.
"""

from __future__ import annotations

import dataclasses
import hashlib
from pathlib import Path

import numpy as np

from amorctl.core.errors import AmorError
from amorctl.motion.cache import cache_dir, cached
from amorctl.motion.clips import MotionLibrary
from amorctl.motion.dataset import load_clip_stats, load_dataset, load_encoder_bytes, write_dataset


def _mismatch(run: MotionLibrary, data: MotionLibrary) -> list[str]:
    problems = []
    if data.character != run.character:
        problems.append(f"character {data.character!r}, the run's is {run.character!r}")
    if tuple(data.joint_names) != tuple(run.joint_names):
        problems.append("joint names or order differ")
    if tuple(data.end_effectors) != tuple(run.end_effectors):
        problems.append(f"end effectors {list(data.end_effectors)} vs {list(run.end_effectors)}")
    if data.fps != run.fps:
        problems.append(f"{data.fps:g} fps, the run's is {run.fps:g}")
    if data.frames.shape[1] != run.frames.shape[1] or data.metadata.get("frame_layout") != run.metadata.get(
        "frame_layout"
    ):
        problems.append(f"frame layout differs ({data.frames.shape[1]} vs {run.frames.shape[1]} features)")
    return problems


def dataset_for_run(run_dataset: Path, data: Path) -> Path:
    """A copy of ``data`` whose latents come from ``run_dataset``'s VAE encoder (cached).

    Returns ``data`` itself when it is the run's dataset.

    Raises:
        AmorError: a file is missing, or ``data`` does not fit the run (named with what differs).
    """
    run_dataset, data = Path(run_dataset), Path(data)
    for path in (run_dataset, data):
        if not path.is_file():
            raise AmorError(f"{path}: motion dataset not found")
    if data.resolve() == run_dataset.resolve():
        return data
    run_lib, lib = load_dataset(run_dataset), load_dataset(data)
    problems = _mismatch(run_lib, lib)
    if problems:
        raise AmorError(f"{data}: does not fit the run's dataset {run_dataset}: {'; '.join(problems)}")
    encoder = load_encoder_bytes(run_dataset)
    digest = hashlib.sha256(data.read_bytes() + (encoder or b"no-vae")).hexdigest()[:24]
    out = cache_dir() / "heldout" / f"{data.stem}-{digest}.mcap"
    starts = np.array([c.start for c in lib.clips], dtype=np.int64)
    lengths = np.array([c.num_frames for c in lib.clips], dtype=np.int64)
    if encoder is None:  # nothing to re-encode with: the file's own latents must have the run's size
        if lib.z.shape[1] != run_lib.z.shape[1]:
            raise AmorError(
                f"{data}: its latents have size {lib.z.shape[1]}, the run's {run_lib.z.shape[1]}, and "
                f"the run's dataset {run_dataset} stores no VAE encoder to re-encode the clips with"
            )
        return data
    from amorctl.motion.vae import encoder_from_bytes

    def build(path: Path) -> None:
        z = encoder_from_bytes(encoder).encode(lib.frames, starts, lengths).astype(np.float32)
        if z.shape[1] != run_lib.z.shape[1]:
            raise AmorError(
                f"{run_dataset}: its encoder gives {z.shape[1]} latents but it stores {run_lib.z.shape[1]}"
            )
        meta = dict(lib.metadata)
        meta["vae"] = run_lib.metadata.get("vae")
        meta["latents_from"] = str(run_dataset)
        write_dataset(
            path,
            dataclasses.replace(lib, z=z, metadata=meta),
            clip_stats=load_clip_stats(data),
            encoder=encoder,
        )

    return cached(out, build, "the held-out dataset with the run's latents")
