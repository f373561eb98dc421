"""amorctl: adaptive character control through multi-objective reinforcement learning."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("amorctl")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0.0.0+unknown"

__all__ = ["__version__"]
