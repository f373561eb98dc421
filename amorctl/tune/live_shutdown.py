"""Ending the live page on Ctrl-C, always and in bounded time: the page's threads are joined with
a deadline, and a watchdog armed by SIGINT ends the process if the shutdown still hangs."""

from __future__ import annotations

import signal
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

SHUTDOWN_TIMEOUT_S = 15.0
#: Ctrl-C always ends the page within this: the loop's join (10 s), the server's stop, the threads
SHUTDOWN_BOUND_S = 10.0 + SHUTDOWN_TIMEOUT_S + 5.0


def on_interrupt(hook: Callable[[], None]) -> Any:
    """Run ``hook`` on SIGINT, then raise KeyboardInterrupt as Python does; returns the previous
    handler (None off the main thread, where signals cannot be handled: nothing is installed)."""
    if threading.current_thread() is not threading.main_thread():
        return None

    def handler(_signum: int, _frame: Any) -> None:
        hook()
        raise KeyboardInterrupt

    return signal.signal(signal.SIGINT, handler)


def shutdown_watchdog(bound_s: float, end: Callable[[int], Any]) -> threading.Timer:
    """End the process (status 0: what the page saved is written and closed) if the page's
    shutdown has not finished ``bound_s`` after Ctrl-C. Seen under load: the server's stop never
    returned, and the process had to be killed."""

    def expire() -> None:
        print(
            f"live page: shutdown did not finish within {bound_s:.0f} s; ending the process", file=sys.stderr
        )
        end(0)

    timer = threading.Timer(bound_s, expire)
    timer.daemon = True
    timer.start()
    return timer


def join_threads(threads: set[threading.Thread], timeout_s: float) -> None:
    """Wait (bounded) for the page's threads to end. The server's threads are daemons and its stop
    waits only a second for them; one still inside the websocket library's C code when the
    interpreter finalizes crashed the process (SIGSEGV at exit on a loaded machine)."""
    deadline = time.monotonic() + timeout_s
    for thread in threads:
        if thread is not threading.current_thread():
            thread.join(timeout=max(0.0, deadline - time.monotonic()))
