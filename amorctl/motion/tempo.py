"""``preprocess --tempo``: play clips slower (or faster) than recorded, before retargeting.

A tempo ``f`` divides every time stamp of the imported motion by ``f``: the poses stay exactly the
source's, the clip lasts ``1/f`` times as long, and every speed (joint, root, end effector) scales
by ``f``. It is how a reference is made to fit actuators that cannot turn as fast as the
performer (docs/preprocess.md, docs/repertoire.md). ``--tempo 0.5`` applies to every clip,
``--tempo run=0.5`` to one (a clip name as ``--motion`` takes it); a named clip's tempo wins over
the bare one.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import TypeVar

from amorctl.core.errors import AmorError
from amorctl.motion.resolve import resolve_name

#: Accepted tempo factors: a tenth to ten times the recorded speed.
TEMPO_RANGE = (0.1, 10.0)

M = TypeVar("M")


@dataclass(frozen=True)
class Tempo:
    """The playback rate of every clip: ``default`` unless ``per_clip`` names it (queries as typed,
    resolved against the clip names by :meth:`resolve`)."""

    default: float = 1.0
    per_clip: dict[str, float] = field(default_factory=dict)

    def resolve(self, names: Sequence[str]) -> dict[str, float]:
        """{clip name: tempo} for every clip of ``names``.

        Raises:
            AmorError: a ``--tempo CLIP=F`` whose CLIP is no clip (or more than one), listing them.
        """
        rates = dict.fromkeys(names, self.default)
        for query, rate in self.per_clip.items():
            try:
                rates[resolve_name(query, list(names), "the motions given")] = rate
            except AmorError as err:
                raise AmorError(f"--tempo {query}={rate:g}: {err}") from None
        return rates


def parse_tempo(values: Sequence[str]) -> Tempo:
    """``--tempo`` values (``F`` or ``CLIP=F``, repeatable) as a :class:`Tempo`.

    Raises:
        AmorError: a factor that is not a number within :data:`TEMPO_RANGE`, two bare factors, or
            a clip named twice.
    """
    default: float | None = None
    per_clip: dict[str, float] = {}
    for value in values:
        clip, _, text = value.rpartition("=")
        try:
            rate = float(text)
        except ValueError:
            raise AmorError(f"--tempo {value!r}: write a factor (0.5) or CLIP=FACTOR (run=0.5)") from None
        low, high = TEMPO_RANGE
        if not (math.isfinite(rate) and low <= rate <= high):
            raise AmorError(f"--tempo {value!r}: the factor must be within [{low:g}, {high:g}]")
        if not clip:
            if default is not None:
                raise AmorError(f"--tempo {value!r}: a factor for every clip was already given ({default:g})")
            default = rate
        elif clip in per_clip:
            raise AmorError(f"--tempo {value!r}: clip {clip!r} was already given a tempo")
        else:
            per_clip[clip] = rate
    return Tempo(1.0 if default is None else default, per_clip)


def retime(motion: M, rate: float) -> M:
    """``motion`` (a SourceMotion or CharacterMotion: anything with ``times`` [T] seconds) played
    at ``rate`` times its speed: time stamps divided by ``rate``, poses unchanged."""
    if rate == 1.0:
        return motion
    return replace(motion, times=motion.times / rate)  # type: ignore[type-var]
