"""The one public module plugin authors import.

A plugin (a character, an objective set, a backend, a motion format or a command) needs
``hookimpl`` to mark its hooks, the spec type it registers, and the contracts and data types its
code receives or returns. All of them are re-exported here, so that amorctl can move its internals
without breaking plugins. The names in ``__all__`` and their signatures are the public API: they
change only as docs/plugins.md ("Compatibility") says, and ``tests/test_api_surface.py`` fails on
any change not recorded in its snapshot::

    from amorctl.api import CharacterSpec, JointSpec, ActuatorModel, hookimpl

    @hookimpl
    def amorctl_register_characters(register):
        register(CharacterSpec(...))

What is here, by plugin kind (see ``docs/plugins.md``):

- every kind: :data:`hookimpl`, :class:`AmorError` (errors the user can fix), ``__version__``,
  :func:`get_registry` (other installed plugins, by name), :class:`MovedWarning` (the
  ``DeprecationWarning`` of an import path that moved);
- characters: :class:`CharacterSpec`, :class:`JointSpec`, :class:`ActuatorModel`,
  :data:`KEYPOINTS`, :data:`JOINT_GROUPS`, :func:`character_from_mjcf` (a spec read from a model
  file), :func:`package_file` (a model inside another installed package) and its lazy form
  :func:`package_model` (a :data:`ModelSource`, resolved on first use), :class:`LazyCharacter` (a
  spec built on first use), :func:`plugin_cache_dir`;
- objective sets: :class:`ObjectiveSetSpec`, :class:`ObjectiveSet`, :class:`TrackingInputs`,
  :class:`FrameParts`, :func:`split_frame`, :func:`frame_dim`;
- backends: :class:`BackendSpec`, :class:`Backend`, :class:`Trainer`, :class:`Policy`,
  :class:`Snapshot`, :class:`SnapshotEnv`, :class:`TrackingView`, :func:`tracking_view`,
  :class:`VectorEnv`, :class:`TrainConfig`, and for distillation :class:`Teacher` with
  :func:`teacher_of` (the teachers a training env carries);
- motion formats: :class:`MotionFormatSpec`, :class:`ImportOptions`, :class:`SourceMotion`,
  :class:`CharacterMotion`, :class:`Skeleton`, :func:`deepmimic_skeleton` (the canonical source
  skeleton), :data:`CANONICAL_JOINTS`, :func:`check_finite`, :func:`check_times`,
  :func:`file_sha256`;
- commands: :class:`CommandSpec` (a ``typer.Typer`` app or click command added to ``amorctl``).

Layer: this module sits above ``motion/`` (format plugins return its motion records) and below
``envs/``; nothing in amorctl below ``plugins/`` imports it.
"""

from __future__ import annotations

from amorctl import __version__
from amorctl.core.config import TrainConfig
from amorctl.core.contracts import (
    Backend,
    ObjectiveSet,
    Policy,
    Snapshot,
    SnapshotEnv,
    Teacher,
    TrackingView,
    Trainer,
    tracking_view,
)
from amorctl.core.errors import AmorError
from amorctl.core.frame_layout import FrameParts, TrackingInputs, frame_dim, split_frame
from amorctl.core.moved import MovedWarning
from amorctl.core.specs import (
    JOINT_GROUPS,
    KEYPOINTS,
    ActuatorModel,
    BackendSpec,
    CharacterSpec,
    CommandSpec,
    ImportOptions,
    JointGroup,
    JointSpec,
    LazyCharacter,
    ModelSource,
    MotionFormatSpec,
    ObjectiveSetSpec,
    PackageModel,
    package_model,
)
from amorctl.core.vecenv import VectorEnv, teacher_of
from amorctl.motion.formats.base import file_sha256
from amorctl.motion.source import (
    CANONICAL_JOINTS,
    CharacterMotion,
    Skeleton,
    SourceMotion,
    check_finite,
    check_times,
    deepmimic_skeleton,
)
from amorctl.registry import get_registry
from amorctl.registry import impl as hookimpl
from amorctl.sim.from_mjcf import character_from_mjcf, package_file, plugin_cache_dir

__all__ = [
    "CANONICAL_JOINTS",
    "JOINT_GROUPS",
    "KEYPOINTS",
    "ActuatorModel",
    "AmorError",
    "Backend",
    "BackendSpec",
    "CharacterMotion",
    "CharacterSpec",
    "CommandSpec",
    "FrameParts",
    "ImportOptions",
    "JointGroup",
    "JointSpec",
    "LazyCharacter",
    "ModelSource",
    "MotionFormatSpec",
    "MovedWarning",
    "ObjectiveSet",
    "ObjectiveSetSpec",
    "PackageModel",
    "Policy",
    "Skeleton",
    "Snapshot",
    "SnapshotEnv",
    "SourceMotion",
    "Teacher",
    "TrackingInputs",
    "TrackingView",
    "TrainConfig",
    "Trainer",
    "VectorEnv",
    "__version__",
    "character_from_mjcf",
    "check_finite",
    "check_times",
    "deepmimic_skeleton",
    "file_sha256",
    "frame_dim",
    "get_registry",
    "hookimpl",
    "package_file",
    "package_model",
    "plugin_cache_dir",
    "split_frame",
    "teacher_of",
    "tracking_view",
]
