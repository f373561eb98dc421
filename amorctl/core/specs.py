"""What plugins provide: character specs, objective sets, backends, motion formats and commands.

These are plain frozen dataclasses (and one protocol) so that plugins stay declarative and the
registry can describe them without running anything. Angles are radians, lengths metres,
torques N·m, rates Hz.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from amorctl.core.errors import AmorError
from amorctl.core.model_source import (  # the model-path bits; re-exported here for plugins
    ModelSource,
    PackageModel,
    _ModelPathField,
    describe_model_source,
    find_package_file,
    package_model,
    resolve_model_source,
)
from amorctl.core.moved import moved_names

__all__ = [
    "JOINT_GROUPS",
    "KEYPOINTS",
    "ActuatorModel",
    "BackendSpec",
    "CharacterSpec",
    "ImportOptions",
    "JointGroup",
    "JointSpec",
    "LazyCharacter",
    "ModelSource",
    "MotionFormatSpec",
    "ObjectiveSetSpec",
    "PackageModel",
    "describe_model_source",
    "find_package_file",
    "package_model",
    "resolve_model_source",
    "set_mjcf_reader",
]

if TYPE_CHECKING:
    from amorctl.core.contracts import Backend, ObjectiveSet

JointGroup = Literal["upper", "lower", "feet"]
JOINT_GROUPS: tuple[JointGroup, ...] = ("upper", "lower", "feet")

#: The reader behind :meth:`CharacterSpec.from_mjcf`. Reading a model needs MuJoCo, which core/
#: does not import: :mod:`amorctl.sim.from_mjcf` installs ``character_from_mjcf`` here when it is
#: imported (``amorctl.api`` imports it, so every plugin has it).
_MJCF_READER: list[Callable[..., CharacterSpec]] = []


def set_mjcf_reader(reader: Callable[..., CharacterSpec]) -> None:
    """Install the function :meth:`CharacterSpec.from_mjcf` calls (done by ``amorctl.sim.from_mjcf``)."""
    _MJCF_READER[:] = [reader]


#: Canonical key points that motion retargeting matches between a source skeleton and a character.
KEYPOINTS: tuple[str, ...] = ("root", "head", "left_hand", "right_hand", "left_foot", "right_foot")


@dataclass(frozen=True)
class JointSpec:
    """One actuated hinge joint, found by ``name`` in the MJCF; its actuator is the one of the same
    name, else the one whose joint transmission drives it.

    ``kp``, ``kd`` and ``torque_limit`` are enforced: written into position actuators (``pd``) or
    used by the servo model (``servo``). ``armature``, ``friction_coulomb`` and ``friction_viscous``
    are written into the joint when given; ``None`` keeps the model file's value.
    """

    name: str
    group: JointGroup
    range: tuple[float, float]  # (lower, upper) in radians
    kp: float  # PD stiffness, N·m/rad
    kd: float  # PD damping, N·m·s/rad
    torque_limit: float  # N·m, symmetric
    armature: float | None = None  # reflected rotor inertia, kg·m²
    friction_coulomb: float | None = None  # MuJoCo frictionloss, N·m
    friction_viscous: float | None = None  # MuJoCo damping, N·m·s/rad


@dataclass(frozen=True)
class ActuatorModel:
    """How PD targets become joint torques, beyond what the MJCF itself expresses.

    ``kind="pd"``: MuJoCo position actuators ("virtual actuators"): torque = kp (q* - q) - kd q̇,
    clipped to ±torque_limit, all inside MuJoCo.

    ``kind="servo"``: a servo computed every physics substep (inside MuJoCo's step as a
    ``dcmotor``, :func:`amorctl.sim.actuators.native_servo`; numpy reference
    :func:`amorctl.sim.actuators.servo_torque`): the PD law on a command delayed by
    ``latency_steps`` physics steps, clipped to a DC motor's torque–speed range (driving torque
    falls linearly from ``torque_limit`` at rest to zero at ``no_load_speed``; braking keeps
    ``torque_limit``). Armature,
    Coulomb friction (``frictionloss``) and viscous friction (``damping``) are native MuJoCo joint
    properties: the three fields here record the values the model file holds for every joint
    (informational); to have amorctl write a value into the model, set it per joint in
    :class:`JointSpec`.
    """

    kind: Literal["pd", "servo"]
    armature: float = 0.0  # reflected rotor inertia, kg·m²
    friction_coulomb: float = 0.0  # N·m
    friction_viscous: float = 0.0  # N·m·s/rad
    no_load_speed: float | None = None  # rad/s; None = no torque–speed limit
    latency_steps: int = 0  # command delay in physics steps


@dataclass(frozen=True)
class CharacterSpec:
    """A simulated character: its model file and everything needed to control and track it.

    ``mjcf_path`` may be given as a path or as a zero-argument callable (a :data:`ModelSource`,
    e.g. :func:`package_model`); it is resolved when first read, and reads as a :class:`Path`.
    ``model_source`` is what was given (listings read it without resolving).
    """

    name: str
    description: str
    mjcf_path: _ModelPathField = _ModelPathField()  # noqa: RUF009  # a descriptor: reads as a Path
    root_body: str
    joints: tuple[JointSpec, ...]  # actuated hinges in MJCF qpos order
    end_effectors: tuple[str, ...]  # body names: hands then feet, (left, right) each
    actuator: ActuatorModel
    standing_height: float  # root height of the default standing pose, m
    min_standing_height: float  # the root must stay above this while holding the pose, m
    keypoints: Mapping[str, str]  # KEYPOINTS name -> body name, used by retargeting
    scale_profile: str = "humanoid"  # which prior-scale column objective sets use ("humanoid" | "robot")
    objective_scales: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    standing_pose: Mapping[str, float] = field(default_factory=dict)  # joint -> angle; others 0
    physics_hz: int = 250
    control_hz: int = 50
    licence: str = ""
    #: How a skeleton animation becomes this character's motion: ``"direct"`` maps the canonical
    #: source joints onto same-named hinges (only for a character built on the DeepMimic
    #: skeleton, like ``humanoid36``); ``"ik"`` solves key-point inverse kinematics (any humanoid).
    retarget: Literal["direct", "ik"] = "ik"
    add_floor: bool = True  # add a ground plane at z = 0 when the model has no plane/height field

    def __getstate__(self) -> dict[str, Any]:
        """Pickled (worker processes) with the resolved path: a callable source may not pickle,
        and whoever receives a spec is about to use its model."""
        state = dict(self.__dict__)
        state["_mjcf_path_source"] = self.mjcf_path
        state.pop("_mjcf_path_resolved", None)
        return state

    @classmethod
    def from_mjcf(cls, path: ModelSource, **options: Any) -> CharacterSpec:
        """A spec whose joints, ranges, gains, limits and standing pose are read from the model file:
        ``amorctl.api.character_from_mjcf(path, **options)`` (``name``, ``groups``,
        ``end_effectors``, ``keypoints`` and what the file cannot say; docs/plugins.md).

        Raises:
            AmorError: a model or argument defect, one line naming the file; or amorctl's model
                reader is not loaded (``CharacterSpec`` imported from ``amorctl.core`` alone).
        """
        if not _MJCF_READER:
            raise AmorError(
                "CharacterSpec.from_mjcf: import CharacterSpec from amorctl.api (it loads the model reader)"
            )
        return _MJCF_READER[0](path, **options)

    @property
    def model_source(self) -> ModelSource:
        """The model file as the plugin gave it (not resolved)."""
        return self.__dict__["_mjcf_path_source"]

    @property
    def model_resolved(self) -> bool:
        """Whether ``mjcf_path`` has been resolved (read) already."""
        return "_mjcf_path_resolved" in self.__dict__

    @property
    def substeps(self) -> int:
        """Physics steps per control step."""
        return self.physics_hz // self.control_hz

    @property
    def num_joints(self) -> int:
        return len(self.joints)

    def joint_names(self, group: JointGroup | None = None) -> tuple[str, ...]:
        """Joint names in qpos order, optionally only one group's."""
        return tuple(j.name for j in self.joints if group is None or j.group == group)

    def group_indices(self, group: JointGroup) -> tuple[int, ...]:
        """Indices into the actuated-joint vector of one group's joints."""
        return tuple(i for i, j in enumerate(self.joints) if j.group == group)


@dataclass(frozen=True)
class LazyCharacter:
    """A character registered by name whose :class:`CharacterSpec` is built when first needed
    (``registry.character(name)``), e.g. by ``character_from_mjcf`` from a model in another
    package: registration then touches no file, and a missing model fails only the commands that
    use this character, with ``build``'s error naming it.
    """

    name: str
    build: Callable[[], CharacterSpec]
    description: str = ""


@dataclass(frozen=True)
class ObjectiveSetSpec:
    """An ordered set of m objectives; ``make(character)`` binds the character's prior scales.

    The returned object computes rewards of shape ``[num_envs, m]``; weights are never part of it.
    """

    name: str
    description: str
    objectives: tuple[str, ...]
    make: Callable[[CharacterSpec], ObjectiveSet]


@dataclass(frozen=True)
class BackendSpec:
    """A backend plugin: ``make(**options)`` returns a :class:`~amorctl.core.contracts.Backend`.

    ``levers`` names the training levers it implements (:data:`amorctl.core.levers.LEVERS`); a
    config that turns on another is refused before training starts.
    """

    name: str
    description: str
    make: Callable[..., Backend]
    levers: frozenset[str] = frozenset()


@dataclass(frozen=True)
class ImportOptions:
    """What a motion importer may need besides the file.

    name: clip name to give (default: the file stem); joint_map: path of a TOML joint map (BVH);
    character: target character name (formats already in a character's joints check against it);
    joint_names: that character's actuated joints, in order; root_body: its root body name;
    licence: recorded in the dataset; extra: format-specific options.
    """

    name: str | None = None
    joint_map: Path | None = None
    character: str | None = None
    joint_names: tuple[str, ...] = ()
    root_body: str | None = None
    licence: str = "unknown (user-supplied file)"
    extra: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class MotionFormatSpec:
    """A motion file format: its name, the file suffixes that imply it, and its loader.

    ``load(path, options)`` reads one file and returns a
    :class:`amorctl.motion.source.SourceMotion` (a skeleton animation, to be retargeted) or a
    :class:`amorctl.motion.source.CharacterMotion` (already in ``options.character``'s joints);
    it raises :class:`amorctl.core.errors.AmorError` naming the file on any defect. The return type
    is checked when a file is imported (the motion records live in ``motion/``, above this layer).
    """

    name: str
    suffixes: tuple[str, ...]  # lower-case, with the dot: (".bvh",)
    load: Callable[[Path, ImportOptions], Any]
    description: str = ""


@dataclass(frozen=True)
class CommandSpec:
    """A subcommand a plugin adds to ``amorctl`` (a robot's calibration, a hardware bridge):
    ``amorctl NAME ...`` runs ``command``, a ``typer.Typer`` app (one command, or a group of
    subcommands) or a click command or group.

    ``name`` is lower-case letters, digits and hyphens, and no built-in command's name;
    ``amorctl --help`` lists it under "Plugin commands" with ``help`` (default: the command's own).
    """

    name: str
    command: Any  # typer.Typer | click.Command: this layer imports neither
    help: str = ""

    def __post_init__(self) -> None:
        if not re.fullmatch(r"[a-z][a-z0-9-]*", self.name):
            raise ValueError(f"command name {self.name!r}: use lower-case letters, digits and hyphens")


# 0.1.0 plugins imported Backend from here (core/moved.py)
__getattr__ = moved_names(__name__, {"Backend": "amorctl.core.contracts"})
