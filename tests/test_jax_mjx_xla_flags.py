"""The XLA CPU flag the jax-mjx backend sets before JAX compiles (docs/backends.md, CPU stall)."""

from __future__ import annotations

from amorctl.plugins.backends.jax_mjx.xla_cpu import disable_concurrency_optimized_scheduler

FLAG = "--xla_cpu_enable_concurrency_optimized_scheduler=false"


def test_the_flag_is_appended_to_existing_flags() -> None:
    env = {"XLA_FLAGS": "--xla_force_host_platform_device_count=2"}
    assert disable_concurrency_optimized_scheduler(env) is True
    assert env["XLA_FLAGS"] == f"--xla_force_host_platform_device_count=2 {FLAG}"
    assert disable_concurrency_optimized_scheduler(env) is False  # once only
    assert env["XLA_FLAGS"].count("concurrency_optimized") == 1


def test_an_empty_environment_gets_the_flag_alone() -> None:
    env: dict[str, str] = {}
    assert disable_concurrency_optimized_scheduler(env) is True
    assert env == {"XLA_FLAGS": FLAG}


def test_a_value_the_user_set_is_kept() -> None:
    env = {"XLA_FLAGS": "--xla_cpu_enable_concurrency_optimized_scheduler=true"}
    assert disable_concurrency_optimized_scheduler(env) is False
    assert env["XLA_FLAGS"] == "--xla_cpu_enable_concurrency_optimized_scheduler=true"


def test_importing_the_backend_sets_it_in_this_process() -> None:
    import os

    import amorctl.plugins.backends.jax_mjx  # noqa: F401

    assert "xla_cpu_enable_concurrency_optimized_scheduler" in os.environ.get("XLA_FLAGS", "")
