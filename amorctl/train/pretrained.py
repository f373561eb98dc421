"""Pretrained runs shipped as package data: ``amorctl/pretrained/<name>/``, opened as ``pretrained:<name>``.

A pretrained entry is a read-only run directory (docs/train.md, "Pretrained runs"):

- ``config.toml``: the run's resolved config; a relative ``env.dataset`` is relative to the entry;
- ``checkpoints/iter_NNNNNN.{safetensors,json}``: ONE checkpoint with the policy's arrays only
  (no optimizer state, no env state);
- ``dataset.mcap``: the motion dataset the run trained on (so nothing is preprocessed on first use);
- ``card.json``: how it was trained (:data:`CARD_KEYS`), ``README.md``: the same for people;
- optionally ``metrics.csv`` (the learning curve) and figures named in the card.

The set of names is whatever entries the folders hold (nothing is hard-coded): the package's own
``amorctl/pretrained/`` first, then every folder of ``$AMORCTL_PRETRAINED_PATH`` (``os.pathsep``
separated; a user's own collection, and how the tests add entries). An entry is a subfolder with a
``card.json`` and a ``config.toml``; the first folder that has a name wins.
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from amorctl.core.errors import AmorError

#: The prefix that names a pretrained run wherever a run directory is expected.
PREFIX = "pretrained:"
#: Environment variable with extra folders of pretrained entries.
PATH_ENV = "AMORCTL_PRETRAINED_PATH"
CARD_FILE = "card.json"
CARD_FORMAT = "amorctl-pretrained/1"
#: What a card records (``figures`` and ``notes`` may be empty).
CARD_KEYS = (
    "format",
    "name",
    "description",
    "character",
    "env_kind",
    "backend",
    "objectives",
    "motions",
    "iteration",
    "env_steps",
    "episodes",
    "wall_time_s",
    "command",
    "commit",
    "source_run",
    "init_from",
    "created_utc",
    "dataset",
    "summary",
    "figures",
    "notes",
    "resumable",
    "stages",
)
NAME_RE = re.compile(r"^[a-z0-9][a-z0-9._-]{0,63}$")


def package_folder() -> Path:
    """The package's own ``amorctl/pretrained/`` folder (it may hold no entry)."""
    return Path(__file__).resolve().parent.parent / "pretrained"


def search_folders() -> list[Path]:
    """Folders searched for entries, in order: the package's, then ``$AMORCTL_PRETRAINED_PATH``'s."""
    extra = [Path(p).expanduser() for p in os.environ.get(PATH_ENV, "").split(os.pathsep) if p.strip()]
    return [package_folder(), *extra]


def is_reference(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` is a ``pretrained:<name>`` reference rather than a directory."""
    return os.fspath(path).startswith(PREFIX)


@dataclass(frozen=True)
class PretrainedEntry:
    """One pretrained run: its name, folder and card (a dict with :data:`CARD_KEYS`)."""

    name: str
    path: Path
    card: dict[str, Any]

    @property
    def reference(self) -> str:
        return f"{PREFIX}{self.name}"


def read_card(folder: Path) -> dict[str, Any]:
    """The ``card.json`` of an entry folder.

    Raises:
        AmorError: missing, not JSON, not an object, or of another format.
    """
    path = folder / CARD_FILE
    try:
        card = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise AmorError(f"{path}: not found (a pretrained entry needs its card)") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise AmorError(f"{path}: not valid JSON: {exc}") from None
    if not isinstance(card, dict) or card.get("format") != CARD_FORMAT:
        raise AmorError(f"{path}: not a pretrained card (format {CARD_FORMAT!r} expected)")
    return card


def entries() -> list[PretrainedEntry]:
    """Every pretrained entry found in :func:`search_folders`, sorted by name (first folder wins).

    A subfolder without ``card.json`` or ``config.toml`` is not an entry and is skipped; a damaged
    card raises, since listing it as fine would hide the problem.
    """
    found: dict[str, PretrainedEntry] = {}
    for folder in search_folders():
        if not folder.is_dir():
            continue
        for sub in sorted(folder.iterdir()):
            if sub.name in found or not (sub / CARD_FILE).is_file() or not (sub / "config.toml").is_file():
                continue
            found[sub.name] = PretrainedEntry(sub.name, sub, read_card(sub))
    return [found[k] for k in sorted(found)]


def resolve(reference: str | os.PathLike[str]) -> PretrainedEntry:
    """The entry of ``pretrained:<name>``.

    Raises:
        AmorError: not a ``pretrained:`` reference, or no entry of that name (the message lists the
            names there are).
    """
    text = os.fspath(reference)
    if not is_reference(text):
        raise AmorError(f"{text}: not a pretrained reference ({PREFIX}<name>)")
    name = text[len(PREFIX) :].strip("/")
    for entry in entries():
        if entry.name == name:
            return entry
    have = ", ".join(e.name for e in entries()) or "none installed"
    raise AmorError(f"{text}: no such pretrained run (have: {have}; see `amorctl runs list --pretrained`)")


def output_folder(name: str, sub: str) -> Path:
    """Where a command writes what it would put into a pretrained run: ``./<name>/<sub>``
    (pretrained entries are read-only; the current directory is the user's)."""
    return Path(name) / sub
