"""Method specs as the commands take them (``--methods``, a study's ``methods:``, a zoo entry's
``baselines:``): ``NAME``, ``NAME:ARG`` (``policy:PATH``) or ``LABEL=SPEC``, reported under
their label. The syntax is every problem's; what a name means is its problem's registry's.
"""

from __future__ import annotations

from collections.abc import Sequence

from qkf.core.config import ConfigError


def spec_label(spec: str) -> str:
    """The label a method spec is reported under, as written (``LABEL=SPEC``: LABEL)."""
    label, sep, _ = spec.partition("=")
    return label.strip() if sep else spec.strip()


def pick_baselines(specs: Sequence[str], wanted: Sequence[str]) -> list[str]:
    """The specs of ``specs`` whose labels are in ``wanted``, in their order; ``ConfigError``
    for a wanted label that is not there (naming those that are), or for none wanted."""
    labels = [spec_label(s) for s in specs]
    unknown = [w for w in wanted if w not in labels]
    if unknown or not wanted:
        raise ConfigError(
            f"--baselines: {', '.join(unknown) or 'none given'}: not among the methods; "
            f"choose from {', '.join(labels)}"
        )
    return [s for s, label in zip(specs, labels, strict=True) if label in wanted]


__all__ = ["pick_baselines", "spec_label"]
