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
        "token": None,
    }


TOKEN = "a-live-page-token-0123456789"


def test_the_live_page_beyond_loopback_needs_a_token() -> None:
    _FakeApp.made.clear()
    for host in ("0.0.0.0", "192.168.1.20", "::"):
        with pytest.raises(AmorError, match="beyond loopback") as info:
            tune_live.serve_live("session", host, 8123, app_class=_FakeApp)  # type: ignore[arg-type]
        assert "AMORCTL_TOKEN=" in str(info.value) and "--token" in str(info.value)
    with pytest.raises(AmorError, match="the token is 5 characters"):
        tune_live.serve_live("session", "0.0.0.0", 8123, app_class=_FakeApp, token="short")  # type: ignore[arg-type]
    assert _FakeApp.made == []  # refused before anything was served


class _Inner:
    """A stand-in for the page: any GET answers 'inner <path>'."""

    def __init__(self) -> None:
        import http.server
        import threading

        class Handler(http.server.BaseHTTPRequestHandler):
            def do_GET(self) -> None:
                body = f"inner {self.path}".encode()
                self.send_response(200)
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, *args: object) -> None:
                pass

        self.server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.port = self.server.server_address[1]
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()


def _get(port: int, path: str, headers: dict[str, str] | None = None, method: str = "GET"):  # type: ignore[no-untyped-def]
    import http.client

    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    try:
        conn.request(method, path, headers=headers or {})
        resp = conn.getresponse()
        return resp.status, dict(resp.getheaders()), resp.read().decode()
    finally:
        conn.close()


def test_the_gate_admits_only_a_browser_that_showed_the_token() -> None:
    from amorctl.tune.live_gate import COOKIE, LiveGate

    inner = _Inner()
    gate = LiveGate("127.0.0.1", 0, inner.port, TOKEN)
    try:
        assert gate.url == f"http://127.0.0.1:{gate.port}/?token={TOKEN}"
        status, _, body = _get(gate.port, "/")
        assert status == 403 and "open the URL with ?token=" in body
        assert _get(gate.port, "/?token=wrong")[0] == 403
        assert _get(gate.port, f"/?token={TOKEN}", method="POST")[0] == 403  # only a GET is let in
        status, headers, _ = _get(gate.port, f"/index.html?x=1&token={TOKEN}")
        assert status == 303 and headers["Location"] == "/index.html?x=1"  # the token leaves the URL
        cookie = headers["Set-Cookie"]
        assert cookie.startswith(f"{COOKIE}=") and "HttpOnly" in cookie and "SameSite=Strict" in cookie
        assert TOKEN not in cookie  # the cookie holds an HMAC of the token, not the token
        value = cookie.split(";")[0]
        status, _, body = _get(gate.port, "/app.js", {"Cookie": f"theme=dark; {value}"})
        assert (status, body) == (200, "inner /app.js")  # relayed to the page
        assert _get(gate.port, "/", {"Cookie": f"{COOKIE}=forged"})[0] == 403
        assert gate.refused == 4
    finally:
        gate.close()
        inner.close()


def test_serve_live_with_a_token_puts_the_page_behind_the_gate() -> None:
    urls: list[str] = []
    seen: dict[str, object] = {}

    class App:
        def __init__(self, session: object, host: str, port: int) -> None:
            seen["bound"] = (host, port)  # the page itself stays on loopback, at a free port
            self.inner = _Inner()
            self.port = self.inner.port

        def start(self) -> None:
            pass

        def wait(self) -> None:  # while serving: the announced URL is the gate's, with the token
            import urllib.parse

            url = urllib.parse.urlsplit(urls[0])
            seen["direct"] = _get(url.port, "/")[0]
            seen["with token"] = _get(url.port, f"{url.path}?{url.query}")[0]
            self.inner.close()
            raise KeyboardInterrupt

    tune_live.serve_live("s", "127.0.0.1", 0, urls.append, app_class=App, token=TOKEN)  # type: ignore[arg-type]
    assert seen == {"bound": ("127.0.0.1", 0), "direct": 403, "with token": 303}
    assert re.fullmatch(rf"http://127\.0\.0\.1:\d+/\?token={TOKEN}", urls[0])


def test_ctrl_c_always_ends_the_page_even_when_its_shutdown_hangs(monkeypatch) -> None:
    """SIGINT arms a watchdog: a shutdown still running after SHUTDOWN_BOUND_S ends the process
    (status 0); one that finishes in time cancels it, and the previous SIGINT handler is back."""
    import os
    import signal
    import threading
    import time

    ended: list[int] = []
    monkeypatch.setattr(tune_live, "end_process", ended.append)
    monkeypatch.setattr(tune_live, "SHUTDOWN_BOUND_S", 0.2)
    monkeypatch.setattr(tune_live, "SHUTDOWN_TIMEOUT_S", 1.0)
    before = signal.getsignal(signal.SIGINT)

    def serve(stuck_s: float) -> None:
        class App(_FakeApp):
            def wait(self) -> None:  # a server thread that takes stuck_s to end, then Ctrl-C
                threading.Thread(target=time.sleep, args=(stuck_s,), daemon=True).start()
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(5)  # interrupted by the signal's KeyboardInterrupt

        tune_live.serve_live("s", "127.0.0.1", 8123, app_class=App)  # type: ignore[arg-type]

    serve(stuck_s=0.8)  # the threads' join outlasts the bound: the watchdog ends the process
    assert ended == [0]
    ended.clear()
    serve(stuck_s=0.0)
    time.sleep(0.4)
    assert ended == [] and signal.getsignal(signal.SIGINT) is before
