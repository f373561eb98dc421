"""``serve_live`` (tune/live.py) serves the app class it is given; the HLP's page is that class."""

from __future__ import annotations

import re
from typing import ClassVar

import pytest

from amorctl.core.errors import AmorError
from amorctl.hlp import live as hlp_live
from amorctl.tune import live as tune_live


class _FakeApp:
    made: ClassVar[list[tuple[object, str, int]]] = []

    def __init__(self, session: object, host: str, port: int) -> None:
        if port == 1:
            raise OSError("address in use")
        self.url = f"http://{host}:{port}/"
        self.started = False
        _FakeApp.made.append((session, host, port))

    def start(self) -> None:
        self.started = True

    def wait(self) -> None:
        assert self.started
        raise KeyboardInterrupt  # Ctrl-C ends serving quietly


def test_serve_live_builds_starts_and_stops_on_ctrl_c() -> None:
    _FakeApp.made.clear()
    urls: list[str] = []
    tune_live.serve_live("session", "127.0.0.1", 8123, urls.append, app_class=_FakeApp)  # type: ignore[arg-type]
    assert _FakeApp.made == [("session", "127.0.0.1", 8123)]
    assert urls == ["http://127.0.0.1:8123/"]
    with pytest.raises(
        AmorError, match=re.escape("cannot serve the live page on 127.0.0.1:1: address in use")
    ):
        tune_live.serve_live("session", "127.0.0.1", 1, app_class=_FakeApp)  # type: ignore[arg-type]


def test_serve_hlp_live_serves_the_hlp_page(monkeypatch) -> None:
    seen = {}
    monkeypatch.setattr(hlp_live, "serve_live", lambda session, **kw: seen.update(session=session, **kw))
    hlp_live.serve_hlp_live("s", host="0.0.0.0", port=9000)  # type: ignore[arg-type]
    assert seen == {
        "session": "s",
        "host": "0.0.0.0",
        "port": 9000,
        "announce": None,
        "app_class": hlp_live.HlpLiveApp,
    }
