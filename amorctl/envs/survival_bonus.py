"""A survival bonus of another size (``[env] survival_bonus_scale``, docs/moppo.md, "Levers").

An objective set may add a survival bonus c to every objective on each step that does not end
the episode (its optional ``alive_bonus``). :class:`ScaledSurvivalBonus` wraps such a set so that
the bonus is ``scale * c`` instead, leaving the tracking terms as they are: with a smaller bonus a
longer episode pays less against a closer one.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from amorctl.core.contracts import survival_bonus_of
from amorctl.core.errors import AmorError
from amorctl.core.frame_layout import TrackingInputs


class ScaledSurvivalBonus:
    """``objectives`` with its survival bonus c replaced by ``scale * c`` (r [N, m]).

    Attributes:
        names, descriptions: the wrapped set's.
        alive_bonus: ``scale * c``.
        low, high: [m] the wrapped bounds; ``high`` moved by the bonus's change.
    """

    def __init__(self, objectives: Any, scale: float) -> None:
        if not (np.isfinite(scale) and scale >= 0):
            raise AmorError(f"survival_bonus_scale must be a finite number >= 0, got {scale}")
        self.inner = objectives
        self.names = tuple(objectives.names)
        self.descriptions = tuple(objectives.descriptions)
        self.delta = (float(scale) - 1.0) * survival_bonus_of(objectives)
        self.alive_bonus = survival_bonus_of(objectives) + self.delta
        # r = t + c * alive with t the bonus-free part: the upper bound has the bonus, the lower
        # one (a terminating step's) does not, for any bonus >= 0.
        self.low = np.asarray(objectives.low, dtype=np.float64)
        self.high = np.asarray(objectives.high, dtype=np.float64) + self.delta

    def __call__(self, inputs: TrackingInputs, alive: Any, xp: Any = np) -> Any:
        """r [N, m]: the wrapped rewards plus ``(scale - 1) * c`` where ``alive`` [N] is 1."""
        r = self.inner(inputs, alive, xp)
        return r + self.delta * xp.asarray(alive, dtype=r.dtype)[:, None]


def scale_survival_bonus(objectives: Any, scale: float) -> Any:
    """``objectives`` itself at scale 1, else wrapped in :class:`ScaledSurvivalBonus`.

    Raises:
        AmorError: ``scale`` is negative or not finite, or the set declares no survival bonus.
    """
    if scale == 1.0:
        return objectives
    if not survival_bonus_of(objectives) > 0:
        raise AmorError(
            f"survival_bonus_scale = {scale:g} needs an objective set with a survival bonus "
            f"(its alive_bonus is {survival_bonus_of(objectives):g})"
        )
    return ScaledSurvivalBonus(objectives, scale)
