"""amorctl: adaptive character control through multi-objective reinforcement learning."""

import os
from importlib.metadata import PackageNotFoundError, version

from amorctl.core.moved import install as _install_moved_paths

# Idle OpenMP threads (torch's intra-op pool) sleep instead of spinning (libgomp's default spins
# ~3 ms after every parallel region): beside another busy process, spinning workers take the
# cores MuJoCo's threads need (docs/environment.md, "Threads and contention"). OpenMP reads this
# once, when torch loads, so it is set before any import of torch; a user's own setting wins.
if "OMP_WAIT_POLICY" not in os.environ and "GOMP_SPINCOUNT" not in os.environ:
    os.environ["OMP_WAIT_POLICY"] = "PASSIVE"

try:
    __version__ = version("amorctl")
except PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0.0.0+unknown"

# Import paths of 0.1.0 that moved keep working, with a DeprecationWarning (core/moved.py).
_install_moved_paths()

__all__ = ["__version__"]
