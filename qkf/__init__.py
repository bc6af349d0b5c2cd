"""qkf: a research gym for adaptive estimation with reinforcement learning.

``qkf.core`` holds what every estimation problem shares (configs, Kalman primitives, statistics,
the Monte Carlo runner, IO, plots); each problem has its own package beside it
(``qkf.transfer_alignment``). See docs/architecture.md.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("qkf")
except PackageNotFoundError:  # pragma: no cover - running from a bare source tree
    __version__ = "0+unknown"
