"""The live page of ``amorctl tune RUN --hlp HLPDIR --live``: the HLP chooses w_t every step, the
sliders are per-objective multipliers on it (:mod:`amorctl.hlp.edit`), and the page shows the
HLP's current w_t beside the edited weights the policy sees."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from amorctl.core.errors import AmorError
from amorctl.hlp.edit import edit_weights
from amorctl.hlp.run import LoadedHlp
from amorctl.hlp.tune import check_hlp_for
from amorctl.tune.live import SLIDER_MAX, LiveApp, LiveSession, serve_live
from amorctl.tune.session import PinnedMotion

#: a slider at SLIDER_MAX multiplies by this; the middle of the slider is x1
MULTIPLIER_MAX = 2.0


class HlpLiveSession(LiveSession):
    """A :class:`~amorctl.tune.live.LiveSession` whose weights are the HLP's w_t, edited.

    Args:
        tenv: the pinned motion.
        hlp: the trained HLP (of a run like ``tenv``'s).
        scales: initial multipliers [m] in [0, MULTIPLIER_MAX] (default 1 each).
        save_to: the schedule file recorded keyframes (edited weights) are saved to.
    """

    def __init__(
        self, tenv: PinnedMotion, hlp: LoadedHlp, scales: np.ndarray | None = None, save_to: str | Path = ""
    ) -> None:
        check_hlp_for(tenv, hlp)
        self.hlp = hlp
        m = len(tenv.names)
        s = np.ones(m) if scales is None else np.asarray(scales, dtype=np.float64)
        if s.shape != (m,) or not np.isfinite(s).all() or (s < 0).any() or (s > MULTIPLIER_MAX).any():
            raise AmorError(f"--scale: the live page's multipliers lie in [0, {MULTIPLIER_MAX:g}]")
        super().__init__(tenv, save_to=save_to)
        self._sliders = s / MULTIPLIER_MAX * SLIDER_MAX

    @property
    def scales(self) -> np.ndarray:
        """[m] the multipliers the sliders set."""
        with self._lock:
            return self._sliders / SLIDER_MAX * MULTIPLIER_MAX

    @property
    def hlp_weights(self) -> np.ndarray:
        """[m] the HLP's w_t for the current observation (unedited)."""
        with self._lock:
            return self.hlp.weights(self.tenv.obs)[0]

    @property
    def weights(self) -> np.ndarray:
        """[m] the HLP's w_t times the multipliers, renormalized (what the next step applies)."""
        with self._lock:
            scales = self.scales
            if not (scales > 0).any():
                return self.hlp_weights
            return edit_weights(self.hlp_weights[None], scales)[0].astype(np.float64)


def _markdown(s: HlpLiveSession) -> str:
    lines = ["| objective | HLP w_t | × | policy sees |", "| --- | --- | --- | --- |"]
    raw, scales, seen = s.hlp_weights, s.scales, s.weights_seen_by_policy
    for i, n in enumerate(s.names):
        shown = "–" if seen is None else f"{seen[i]:.3f}"
        lines.append(f"| {n} | {raw[i]:.3f} | {scales[i]:.2f} | {shown} |")
    return "\n".join(lines)


class HlpLiveApp(LiveApp):
    """The live page with the HLP's w_t, the multipliers and the edited weights in one table."""

    def _build_gui(self) -> None:
        super()._build_gui()
        self.server.gui.add_markdown(
            f"**HLP mode** ({self.session.hlp.dir.path.name}): the sliders multiply the HLP's w_t by "
            f"0–{MULTIPLIER_MAX:g} (the middle is ×1); the result is renormalized."
        )

    def _refresh_text(self) -> None:
        super()._refresh_text()
        self.weights_md.content = _markdown(self.session)


def serve_hlp_live(
    session: HlpLiveSession,
    host: str = "127.0.0.1",
    port: int = 8080,
    announce: Callable[[str], None] | None = None,
    token: str | None = None,
) -> None:
    """Serve ``session`` on the HLP's live page until interrupted (Ctrl-C); beyond loopback only
    with a shared ``token`` (:func:`amorctl.tune.live.serve_live`)."""
    serve_live(session, host=host, port=port, announce=announce, app_class=HlpLiveApp, token=token)
