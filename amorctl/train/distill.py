"""The teachers of a distillation run (``[distill] teachers``, docs/distill.md).

A student policy learns every clip of its dataset from the frozen policy of a run that tracks that
clip (a teacher), on the states the student visits itself (DAgger without the teacher's actions in
the loop). This module loads the teachers once, before anything is written, and checks that each
one sees exactly what the student sees: the same character, objectives, action mode and
observation size, and, clip by clip, the same reference frames and motion latents (a teacher
trained with ``--clips`` on a subset of the student's dataset qualifies; one trained on another
preprocessing of the same motion does not, since its latents differ). Each clip goes to the first
teacher, in the order given, whose dataset holds it; a clip no teacher holds is refused.

The trainer receives the teachers through the env (:class:`Taught`, read with
:func:`amorctl.core.vecenv.teacher_of`), so the backend contract stays ``make_trainer(env,
config)``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from amorctl.core.config import TrainConfig
from amorctl.core.contracts import Policy, tracking_view
from amorctl.core.errors import AmorError
from amorctl.motion.clips import MotionLibrary
from amorctl.train import pretrained
from amorctl.train.rundir import RunDir

#: ``[env]`` fields a teacher's run must share with the student's (they shape what actions mean)
SHARED_ENV = ("character", "objective_set", "action_mode")


@dataclass(frozen=True)
class ClipTeachers:
    """Frozen teacher policies and which one teaches each clip (implements
    :class:`~amorctl.core.contracts.Teacher`).

    Attributes:
        policies: one inference policy per teacher.
        log_stds: [A] float32 per teacher, its Gaussian's state-independent log std.
        clip_teacher: [C] int, the teacher index of each of the student's clips.
        labels: each teacher as the user named it (``pretrained:NAME`` or an absolute path).
        checkpoints: each teacher's checkpoint file name (``iter_NNNNNN.json``), recorded so a
            resumed student can tell whether a teacher moved on.
    """

    policies: tuple[Policy, ...]
    log_stds: tuple[np.ndarray, ...]
    clip_teacher: np.ndarray
    labels: tuple[str, ...]
    checkpoints: tuple[str, ...]

    def __call__(self, obs: np.ndarray, clips: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Raw observations [B, D], clip indices [B] -> (teacher action mean [B, A], log std [B, A])."""
        obs = np.asarray(obs, dtype=np.float32)
        teacher = self.clip_teacher[np.asarray(clips, dtype=np.int64)]
        action_dim = self.log_stds[0].shape[0]
        mean = np.empty((obs.shape[0], action_dim), dtype=np.float32)
        log_std = np.empty_like(mean)
        for k, policy in enumerate(self.policies):
            rows = np.flatnonzero(teacher == k)
            if rows.size:
                mean[rows] = policy(obs[rows])
                log_std[rows] = self.log_stds[k]
        return mean, log_std

    def fingerprint(self) -> list[str]:
        """``label@checkpoint`` per teacher: what a resumed student checks its teachers against."""
        return [f"{label}@{ckpt}" for label, ckpt in zip(self.labels, self.checkpoints, strict=True)]


class Taught:
    """The training env with its teachers attached (``env.teacher``); everything else is the env's."""

    def __init__(self, env: Any, teacher: ClipTeachers) -> None:
        self.env = env
        self.teacher = teacher

    def __getattr__(self, name: str) -> Any:
        return getattr(self.env, name)

    def tracking_view(self) -> Any:
        """The wrapped env's tracking view."""
        return tracking_view(self.env)


def record_teachers(config: TrainConfig) -> TrainConfig:
    """A new run's config with its teacher run directories stored absolute (so a later stage
    resumes from any directory); ``pretrained:`` names stay as they are."""
    teachers = config.distill.teachers
    if not teachers:
        return config
    stored = tuple(t if pretrained.is_reference(t) else str(Path(t).resolve()) for t in teachers)
    return dataclasses.replace(config, distill=dataclasses.replace(config.distill, teachers=stored))


def load_teachers(config: TrainConfig, env: Any, library: MotionLibrary) -> ClipTeachers:
    """The teachers of ``config`` for the student's ``env`` (its tracking view names the clips)
    and its motion ``library``, checked clip by clip (module docstring).

    Raises:
        AmorError: naming ``[distill] teachers``, the teacher and the mismatch: a run that cannot be
            opened, another character, objective set or action mode, other observation or action
            sizes, a clip whose frames or latents differ from the student's, a clip no teacher has.
    """
    view = tracking_view(env)
    if view is None:
        raise AmorError("[distill] teachers need the tracking env (env.kind = 'tracking')")
    student_clips = tuple(view.clip_names)
    clip_teacher = np.full(len(student_clips), -1, dtype=np.int64)
    policies, log_stds, labels, checkpoints = [], [], [], []
    for k, ref in enumerate(config.distill.teachers):
        where = f"[distill] teachers: {ref}"
        run = _open_teacher(ref, where)
        teacher_config = run.config
        _check_same_env(config, teacher_config, where)
        ckpt = run.checkpoint()
        policy = run.policy_of(ckpt)
        _check_sizes(policy, env, where)
        teacher_library = _library_of(run, where)
        held = _clips_held(library, teacher_library, where)
        for index, name in enumerate(student_clips):
            if clip_teacher[index] < 0 and name in held:
                clip_teacher[index] = k
        policies.append(policy)
        log_stds.append(action_log_std(policy))
        labels.append(run.label)
        checkpoints.append(ckpt.path.name)
    missing = [name for name, k in zip(student_clips, clip_teacher, strict=True) if k < 0]
    if missing:
        raise AmorError(
            f"[distill] teachers: no teacher holds the clips {', '.join(missing)} of the student's "
            "dataset; add a run trained on them, or train the student on the taught clips only (--clips)"
        )
    return ClipTeachers(tuple(policies), tuple(log_stds), clip_teacher, tuple(labels), tuple(checkpoints))


def action_log_std(policy: Policy) -> np.ndarray:
    """The policy's state-independent log std of its Gaussian actions [A] (``actor/log_std``)."""
    return np.asarray(policy.export_arrays().arrays["actor/log_std"], dtype=np.float32)


def student_library(config: TrainConfig) -> MotionLibrary:
    """The motion library a tracking config trains on (its dataset, else the built-in clips)."""
    from amorctl.motion.cache import default_dataset
    from amorctl.motion.dataset import load_dataset

    path = Path(config.env.dataset) if config.env.dataset else default_dataset(config.env.character)
    return load_dataset(path)


def _open_teacher(ref: str, where: str) -> RunDir:
    try:
        return RunDir.open(ref)
    except AmorError as err:
        raise AmorError(f"{where}: {err}") from None


def _check_same_env(student: TrainConfig, teacher: TrainConfig, where: str) -> None:
    if teacher.env.kind != "tracking":
        raise AmorError(f"{where}: not a motion-tracking run (env.kind = {teacher.env.kind!r})")
    for key in SHARED_ENV:
        mine, theirs = getattr(student.env, key), getattr(teacher.env, key)
        if mine != theirs:
            raise AmorError(
                f"{where}: the teacher was trained with [env] {key} = {theirs!r}, the student has {mine!r}"
            )


def _check_sizes(policy: Policy, env: Any, where: str) -> None:
    student = (env.obs_dim, env.action_dim, tuple(env.reward_space.names))
    teacher = (policy.obs_dim, policy.action_dim, tuple(policy.objectives))
    if teacher != student:
        raise AmorError(
            f"{where}: the teacher's observations, actions and objectives {teacher} differ from the "
            f"student's {student}"
        )


def _library_of(run: RunDir, where: str) -> MotionLibrary:
    from amorctl.motion.dataset import load_dataset

    path = run.dataset_path()
    if path is None:  # pragma: no cover - tracking runs always have one
        raise AmorError(f"{where}: the run has no motion dataset")
    try:
        return load_dataset(path)
    except AmorError as err:
        raise AmorError(f"{where}: {err}") from None


def _clips_held(student: MotionLibrary, teacher: MotionLibrary, where: str) -> set[str]:
    """The student's clips the teacher trained on, each checked to have the student's frames and
    latents. Raises AmorError for a clip of the same name with other data."""
    theirs = {clip.name: clip for clip in teacher.clips}
    held = set()
    for clip in student.clips:
        other = theirs.get(clip.name)
        if other is None:
            continue
        mine_rows = slice(clip.start, clip.start + clip.num_frames)
        their_rows = slice(other.start, other.start + other.num_frames)
        same = (
            clip.num_frames == other.num_frames
            and np.array_equal(student.frames[mine_rows], teacher.frames[their_rows])
            and np.array_equal(student.z[mine_rows], teacher.z[their_rows])
        )
        if not same:
            raise AmorError(
                f"{where}: clip {clip.name!r} has other frames or motion latents than in the student's "
                "dataset; a teacher must have trained on the same preprocessed clips (the student's "
                "dataset, or a subset of it written with --clips)"
            )
        held.add(clip.name)
    return held
