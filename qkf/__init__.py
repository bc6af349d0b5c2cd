"""qkf: a research gym for adaptive estimation with reinforcement learning.

``qkf.core`` holds what every estimation problem shares (configs, Kalman primitives, statistics,
the Monte Carlo runner, IO, plots); each problem has its own package beside it
(``qkf.transfer_alignment``). See docs/architecture.md.
"""

from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

from qkf.core.numba_cache import discard_stale_caches

# Before any compiled function is called: numba's cached code of one module can hold a stale
# copy of another's (qkf.core.numba_cache).
discard_stale_caches(Path(__file__).resolve().parent)

try:
    __version__ = version("qkf")
except PackageNotFoundError:  # pragma: no cover - running from a bare source tree
    __version__ = "0+unknown"
