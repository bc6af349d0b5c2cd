"""Scenario checks of the environments: what ``qkf train`` reports before any work.

Every environment takes ``scenario`` (a preset name, a config path) and ``overrides``
(``--set`` style), loaded by its problem's config loader. :func:`scenario_problems` turns what
that loader refuses into one message line per problem, ``scenario: …`` for the file itself and
``overrides: …`` for what the overrides break, so a training config can be judged whole.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from qkf.core.config import ConfigError

Loader = Callable[[str, list[str] | None], Any]
"""A problem's ``load_config(path or preset name, overrides)``; raises ``ConfigError``."""


def message_lines(exc: ConfigError) -> list[str]:
    """The problem lines of a ``ConfigError`` (its ``invalid …`` header dropped)."""
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    if len(lines) > 1 and lines[0].startswith("invalid "):
        lines = lines[1:]
    return lines


def scenario_problems(
    load: Loader,
    scenario: str,
    overrides: Sequence[str],
    episode_check: Callable[[Any], None] | None = None,
) -> list[str]:
    """Problems of ``scenario`` with ``overrides`` (empty: none), each ``KEY: message``.

    ``load``: the problem's config loader; ``episode_check(cfg)``: what the environment needs
    beyond a valid config (say, a gyro to calibrate), ``ValueError`` naming what is missing.
    The scenario alone is loaded first, so a bad file is blamed on ``scenario`` and a bad
    override on ``overrides``.
    """
    if Path(scenario).is_dir():
        return [f"scenario: {scenario}: is a directory, not a scenario file"]
    try:
        cfg = load(scenario, None)
    except ConfigError as exc:
        return [f"scenario: {line}" for line in message_lines(exc)]
    if overrides:
        try:
            cfg = load(scenario, list(overrides))
        except ConfigError as exc:
            return [f"overrides: {line}" for line in message_lines(exc)]
    if episode_check is not None:
        try:
            episode_check(cfg)
        except ValueError as exc:  # ConfigError included
            return [f"scenario: {line}" for line in message_lines(ConfigError(str(exc)))]
    return []
