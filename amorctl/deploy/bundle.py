"""The deploy bundle: ``policy.onnx`` + ``deploy.json`` + ``motions.npz`` + ``model/``, read and validated.

Torch-free (numpy, mujoco, onnxruntime and the standard library): the runtime and robot-side
tools read bundles through this module. The format, every metadata key and the ONNX signature
are documented in docs/deploy.md; :mod:`amorctl.deploy.export` writes bundles.

Validation on read (each failure is one AmorError naming the file): ``deploy.json`` is JSON with
every key of :data:`METADATA_KEYS` and this :data:`FORMAT`; ``policy.onnx`` loads in onnxruntime,
has the inputs and outputs ``deploy.json`` lists and carries the same metadata (JSON-encoded, in
``metadata_props``); ``motions.npz`` matches its recorded SHA-256 and shapes; and, for a character
bundle, every file of ``model/`` (the character's MJCF, the files it reads and its licence, copied
at export) is there and the model compiled from them hashes to ``model_sha256``. The runtime
simulates that copy: nothing outside the bundle is read. (Bundles exported by earlier versions
point at the model inside the installed plugin package instead, ``plugin_module``; they still read.)
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from amorctl.core.errors import AmorError
from amorctl.core.frame_layout import STATE_ARRAYS, frame_dim
from amorctl.core.observation import observation_layout
from amorctl.core.specs import ActuatorModel, CharacterSpec, JointSpec

FORMAT = "amorctl-deploy/1"
ONNX_FILE = "policy.onnx"
META_FILE = "deploy.json"
MOTIONS_FILE = "motions.npz"
#: folder of the bundle holding the character's model files (``character_model["mjcf"]`` is in it).
MODEL_DIR = "model"
#: ONNX opset of every exported policy (fixed, so robot-side runtimes know what to support).
OPSET = 17
#: observation parts that are motion context: each becomes its own ONNX input.
CONTEXT_PARTS = ("ref_frame", "latent", "future_frames")
#: the keys of ``deploy.json`` and of the ONNX ``metadata_props`` (docs/deploy.md describes each).
METADATA_KEYS = (
    "format",
    "amorctl_version",
    "run",
    "iteration",
    "objectives",
    "objective_set",
    "inputs",
    "outputs",
    "observation_layout",
    "action",
    "joint_names",
    "joint_ranges",
    "pd_gains",
    "torque_limits",
    "actuator_model",
    "default_pose",
    "control_hz",
    "physics_hz",
    "character",
    "model_sha256",
    "character_model",
    "termination",
    "context",
    "motions",
    "opset",
    "parity",
)
#: arrays of ``motions.npz`` (world-frame arrays for reference-state init, the context, latents).
MOTION_ARRAYS = (
    "frames",
    "z",
    *STATE_ARRAYS,
    "clip_starts",
    "clip_lengths",
    "clip_names",
)


# ---------------------------------------------------------------------------- element names


def frame_element_names(
    joints: tuple[str, ...] | list[str], end_effectors: tuple[str, ...] | list[str]
) -> list[str]:
    """The D = 13 + 2J + 12E element names of a frame vector (layout of docs/observations.md)."""
    names = ["h", *(f"root_rot6d/{i}" for i in range(6))]
    names += [f"root_lin_vel/{a}" for a in "xyz"] + [f"root_ang_vel/{a}" for a in "xyz"]
    names += [f"joint_pos/{j}" for j in joints] + [f"joint_vel/{j}" for j in joints]
    for e in end_effectors:
        names += [f"ee_pos/{e}/{a}" for a in "xyz"] + [f"ee_rot6d/{e}/{i}" for i in range(6)]
    names += [f"ee_vel/{e}/{a}" for e in end_effectors for a in "xyz"]
    return names


def part_element_names(
    part: str,
    size: int,
    joints: list[str],
    end_effectors: list[str],
    objectives: list[str],
) -> list[str]:
    """Element names of one observation part (``proprio``, ``prev_targets``, ``ref_frame``, ...)."""
    frame = frame_element_names(joints, end_effectors) if joints else []
    if part in ("proprio", "ref_frame") and len(frame) == size:
        return [f"{part}/{n}" for n in frame]
    if part == "prev_targets" and size == 2 * len(joints):
        return [f"prev_targets/t-1/{j}" for j in joints] + [f"prev_targets/t-2/{j}" for j in joints]
    if part == "future_frames" and frame and size % len(frame) == 0:
        return [f"future_frames/{k}/{n}" for k in range(size // len(frame)) for n in frame]
    if part == "weights" and size == len(objectives):
        return [f"w/{o}" for o in objectives]
    return [f"{part}/{i}" for i in range(size)]


# ---------------------------------------------------------------------------- the character


#: ``MjModel`` fields that say where the asset files were found (and the buffer size that holds
#: those paths), not what the model is.
_LOCATION_FIELDS = ("paths", "npaths", "nbuffer")


def _digest_fields(digest: Any, obj: Any, prefix: str, depth: int) -> None:
    """Feed every public number, string and array of a MuJoCo struct (nested structs to ``depth``),
    by sorted name, into ``digest``; the asset locations (:data:`_LOCATION_FIELDS`, ``*_pathadr``)
    are left out."""
    for name in sorted(dir(obj)):
        if name.startswith("_") or name in _LOCATION_FIELDS or name.endswith("pathadr"):
            continue
        value = getattr(obj, name)
        key = f"{prefix}{name}".encode()
        if isinstance(value, np.ndarray):
            digest.update(key + str(value.dtype).encode() + str(value.shape).encode())
            digest.update(np.ascontiguousarray(value).tobytes())
        elif isinstance(value, (bool, int, float, str, bytes)):
            digest.update(key + b"=" + repr(value).encode())
        elif not callable(value) and depth > 0:
            _digest_fields(digest, value, f"{prefix}{name}.", depth - 1)


def model_sha256(model: mujoco.MjModel) -> str:
    """SHA-256 of a compiled model: every size, option and array of it (names, masses, geometry,
    mesh vertices, actuators, ...), by field name, except where its asset files were found on disk
    (MuJoCo keeps their absolute paths), so the same model compiled from another directory (a
    bundle's copy) hashes the same. Equal models give equal hashes for one MuJoCo version."""
    digest = hashlib.sha256(f"mujoco {mujoco.__version__}\n".encode())
    _digest_fields(digest, model, "", depth=2)
    return digest.hexdigest()


def mjb_sha256(model: mujoco.MjModel) -> str:
    """SHA-256 of a compiled model's binary (MJB) form, asset paths included: what bundles
    exported before models were copied into them record as ``model_sha256``."""
    buf = np.zeros(mujoco.mj_sizeModel(model), dtype=np.uint8)
    mujoco.mj_saveModel(model, None, buf)
    return hashlib.sha256(buf.tobytes()).hexdigest()


def bundled_mjcf(path: Path, character_model: dict[str, Any]) -> Path:
    """The MJCF the bundle at ``path`` simulates: its own copy (``character_model["mjcf"]``,
    relative to the bundle, every file of ``model_files`` present), or, for a bundle exported
    before models were copied (``plugin_module``), the installed plugin's file."""
    if "plugin_module" in character_model and "model_files" not in character_model:
        return installed_mjcf(character_model)
    missing = [rel for rel in character_model.get("model_files", {}) if not (path / rel).is_file()]
    if missing:
        raise AmorError(
            f"{path / missing[0]}: missing from the bundle ({len(missing)} model file(s)): copy the whole "
            "bundle directory, or export it again"
        )
    mjcf = path / str(character_model.get("mjcf", ""))
    if not mjcf.is_file():
        raise AmorError(f"{mjcf}: the bundle's model file is missing: export the bundle again")
    return mjcf


#: What to do when an old bundle's installed character is missing.
_REEXPORT = ": install it, or export the bundle again (bundles now carry their model)"


def installed_mjcf(character_model: dict[str, Any]) -> Path:
    """The installed character's MJCF: ``character_model["mjcf"]`` relative to the directory of its
    plugin package ``character_model["plugin_module"]`` (found without importing the plugin)."""
    module = str(character_model.get("plugin_module", ""))
    try:
        found = importlib.util.find_spec(module) if module else None
    except (ImportError, ValueError):
        found = None
    if found is None:
        raise AmorError(f"character plugin module {module!r} is not installed{_REEXPORT}")
    if found.submodule_search_locations:
        base = Path(next(iter(found.submodule_search_locations)))
    elif found.origin:
        base = Path(found.origin).parent
    else:
        raise AmorError(f"character plugin module {module!r} has no files{_REEXPORT}")
    path = base / str(character_model.get("mjcf", ""))
    if not path.is_file():
        raise AmorError(f"{path}: the installed character has no model file there{_REEXPORT}")
    return path


def character_spec(meta: dict[str, Any], mjcf_path: Path) -> CharacterSpec:
    """A :class:`CharacterSpec` rebuilt from bundle metadata and the installed MJCF path."""
    cm = meta["character_model"]
    kp, kd = meta["pd_gains"]["kp"], meta["pd_gains"]["kd"]
    joints = tuple(
        JointSpec(
            name=n, group=g, range=(float(r[0]), float(r[1])), kp=float(p), kd=float(d), torque_limit=float(t)
        )
        for n, g, r, p, d, t in zip(
            meta["joint_names"],
            cm["joint_groups"],
            meta["joint_ranges"],
            kp,
            kd,
            meta["torque_limits"],
            strict=True,
        )
    )
    return CharacterSpec(
        name=str(meta["character"]),
        description="",
        mjcf_path=mjcf_path,
        root_body=str(cm["root_body"]),
        joints=joints,
        end_effectors=tuple(cm["end_effectors"]),
        actuator=ActuatorModel(**meta["actuator_model"]),
        standing_height=float(cm["standing_height"]),
        min_standing_height=float(cm["min_standing_height"]),
        keypoints={},
        physics_hz=int(meta["physics_hz"]),
        control_hz=int(meta["control_hz"]),
        scale_profile=str(cm.get("scale_profile", "humanoid")),
        objective_scales={str(k): dict(v) for k, v in cm.get("objective_scales", {}).items()},
    )


def compiled_model_hash(spec: CharacterSpec, *, legacy: bool = False) -> str:
    """Hash (:func:`model_sha256`; ``legacy``: :func:`mjb_sha256`) of the character's MJCF compiled as
    :func:`amorctl.sim.model.load_model` compiles it."""
    from amorctl.sim.model import load_model

    return (mjb_sha256 if legacy else model_sha256)(load_model(spec))


# ---------------------------------------------------------------------------- motions


@dataclass(frozen=True)
class Motions:
    """The reference clips of a bundle (F frames over C clips; shapes as MotionLibrary's).

    ``frames`` [F, D] float32 (the context), ``z`` [F, L] float32, world-frame arrays float64
    (``root_pos`` [F, 3], ``root_quat`` [F, 4], ``root_lin_vel`` [F, 3], ``root_ang_vel`` [F, 3],
    ``joint_pos`` [F, J], ``joint_vel`` [F, J], ``ee_pos`` [F, E, 3], ``ee_quat`` [F, E, 4],
    ``ee_lin_vel`` [F, E, 3]), ``clip_starts`` / ``clip_lengths`` [C] int64, ``clip_names`` [C].
    """

    arrays: dict[str, np.ndarray]

    def __getattr__(self, name: str) -> np.ndarray:
        try:
            return self.__dict__["arrays"][name]
        except KeyError:
            raise AttributeError(name) from None

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(str(n) for n in self.arrays["clip_names"])

    def resolve(self, query: str | None) -> int:
        """Index of the clip ``query`` names (exact, unique prefix or suffix); None: the first."""
        from amorctl.motion.resolve import resolve_name

        if query is None:
            return 0
        return self.names.index(resolve_name(query, self.names, "the bundle"))

    def seconds(self, clip: int, fps: float) -> float:
        """Duration of clip ``clip`` at ``fps``."""
        return float(self.clip_lengths[clip] - 1) / fps


def load_motions(path: Path, sha256: str | None = None) -> Motions:
    """Read ``motions.npz`` (no pickle), checking its hash and that every array is there."""
    if not path.is_file():
        raise AmorError(f"{path}: motions file missing from the bundle")
    data = path.read_bytes()
    if sha256 is not None and hashlib.sha256(data).hexdigest() != sha256:
        raise AmorError(f"{path}: SHA-256 differs from the one deploy.json records (damaged or altered)")
    try:
        with np.load(path, allow_pickle=False) as npz:
            arrays = {k: np.asarray(npz[k]) for k in npz.files}
    except (OSError, ValueError) as exc:
        raise AmorError(f"{path}: not a readable npz file: {exc}") from None
    missing = [k for k in MOTION_ARRAYS if k not in arrays]
    if missing:
        raise AmorError(f"{path}: lacks arrays {', '.join(missing)}")
    f = arrays["frames"].shape[0]
    if any(arrays[k].shape[0] != f for k in MOTION_ARRAYS[:11]):
        raise AmorError(f"{path}: motion arrays do not all have {f} frames")
    return Motions(arrays)


# ---------------------------------------------------------------------------- the bundle


@dataclass
class Bundle:
    """A read, validated bundle.

    Attributes:
        path: the bundle directory.
        meta: ``deploy.json`` (equal to the ONNX metadata).
        session: the onnxruntime session of ``policy.onnx``.
        motions: the reference clips (None for runs without motions).
        spec: the character rebuilt from the metadata and the installed MJCF (None without one).
    """

    path: Path
    meta: dict[str, Any]
    session: Any
    motions: Motions | None
    spec: CharacterSpec | None

    @property
    def objectives(self) -> tuple[str, ...]:
        return tuple(self.meta["objectives"])

    @property
    def input_names(self) -> tuple[str, ...]:
        return tuple(self.meta["inputs"])

    def evaluate(self, feeds: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Run the ONNX policy: ``feeds`` {input name: [B, n] float32} -> {output name: [B, k]}."""
        names = list(self.meta["outputs"])
        out = self.session.run(names, {k: np.asarray(v, dtype=np.float32) for k, v in feeds.items()})
        return dict(zip(names, out, strict=True))


def read_meta(path: Path) -> dict[str, Any]:
    """``deploy.json`` of a bundle directory, checked for format and keys."""
    meta_path = path / META_FILE
    if not path.is_dir():
        raise AmorError(f"{path}: not a deploy bundle (directory not found)")
    if not meta_path.is_file():
        raise AmorError(f"{meta_path}: not found (not a deploy bundle)")
    try:
        meta = json.loads(meta_path.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise AmorError(f"{meta_path}: not valid JSON ({exc})") from None
    if not isinstance(meta, dict):
        raise AmorError(f"{meta_path}: expected a JSON object")
    if meta.get("format") != FORMAT:
        raise AmorError(f"{meta_path}: format {meta.get('format')!r}, this amorctl reads {FORMAT!r}")
    missing = [k for k in METADATA_KEYS if k not in meta]
    if missing:
        raise AmorError(f"{meta_path}: lacks keys {', '.join(missing)}")
    return meta


def open_session(onnx_path: Path, threads: int = 1) -> Any:
    """An onnxruntime CPU session of ``onnx_path``; AmorError if it does not load."""
    import onnxruntime as ort

    if not onnx_path.is_file():
        raise AmorError(f"{onnx_path}: not found")
    options = ort.SessionOptions()
    options.intra_op_num_threads = int(threads)
    options.inter_op_num_threads = 1
    options.log_severity_level = 3
    try:
        return ort.InferenceSession(str(onnx_path), options, providers=["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime raises its own exception types for bad files
        raise AmorError(
            f"{onnx_path}: onnxruntime cannot load it ({str(exc).splitlines()[0][:200]})"
        ) from None


def read_bundle(path: str | Path, *, check_model: bool = True) -> Bundle:
    """Read and validate a bundle (see the module docstring). ``check_model=False`` skips the
    compiled-model hash check (faster; the model files are still required)."""
    path = Path(path)
    meta = read_meta(path)
    onnx_path = path / ONNX_FILE
    session = open_session(onnx_path)
    stored = dict(session.get_modelmeta().custom_metadata_map)
    for key in METADATA_KEYS:
        try:
            value = json.loads(stored[key])
        except (KeyError, json.JSONDecodeError):
            raise AmorError(f"{onnx_path}: metadata {key!r} missing or not JSON") from None
        if value != meta[key]:
            raise AmorError(f"{onnx_path}: metadata {key!r} differs from {path / META_FILE}")
    have_in = [i.name for i in session.get_inputs()]
    have_out = [o.name for o in session.get_outputs()]
    if have_in != list(meta["inputs"]) or have_out != list(meta["outputs"]):
        raise AmorError(f"{onnx_path}: inputs {have_in} / outputs {have_out} differ from {META_FILE}")
    motions = None
    if meta["motions"] is not None:
        motions = load_motions(path / meta["motions"]["file"], meta["motions"]["sha256"])
    spec = None
    if meta["character"] is not None:
        mjcf = bundled_mjcf(path, meta["character_model"])
        spec = character_spec(meta, mjcf)
        if check_model:
            compiled = compiled_model_hash(spec, legacy="model_files" not in meta["character_model"])
            if compiled != meta["model_sha256"]:
                raise AmorError(
                    f"{path / META_FILE}: model_sha256 {meta['model_sha256'][:12]}… differs from the model "
                    f"it runs ({compiled[:12]}…, {mjcf}): its model files were altered, or (an old bundle) "
                    f"the installed character {meta['character']} changed since export; export it again"
                )
    if spec is not None and motions is not None:
        _check_layout(path, meta, spec, motions)
    return Bundle(path=path, meta=meta, session=session, motions=motions, spec=spec)


def _check_layout(path: Path, meta: dict[str, Any], spec: CharacterSpec, motions: Motions) -> None:
    """Refuse a bundle whose observation layout is not the one the tracking envs build
    (:func:`amorctl.core.observation.observation_layout`) for its character, latents, future
    frames and objectives: the runtime assembles observations by that one definition."""
    joints, effectors = spec.num_joints, len(spec.end_effectors)
    offsets = meta["context"]["future_frame_offsets"]
    want = observation_layout(
        frame_dim(joints, effectors), joints, int(motions.z.shape[1]), offsets, len(meta["objectives"])
    )
    have = {k: tuple(v) for k, v in meta["observation_layout"].items()}
    expected = {k: (s.start, s.stop) for k, s in want.items()}
    if have != expected:
        raise AmorError(
            f"{path / META_FILE}: observation_layout {have} is not the layout of this amorctl's tracking "
            f"envs ({expected}); export the bundle again with this version"
        )
