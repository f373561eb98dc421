"""Shared fixtures: a fresh plugin registry per test, so environment variables take effect."""

from __future__ import annotations

import pytest

from amorctl.registry import reset_registry


@pytest.fixture(autouse=True)
def _fresh_registry(monkeypatch: pytest.MonkeyPatch):
    monkeypatch.delenv("AMORCTL_BLOCK_PLUGINS", raising=False)
    monkeypatch.delenv("AMORCTL_TRACE_HOOKS", raising=False)
    monkeypatch.delenv("AMORCTL_DEBUG", raising=False)
    reset_registry()
    yield
    reset_registry()
