"""Ways of choosing the process-noise factor κ of the transfer-alignment filter (SPEC §3).

Every method filters all trials of a :class:`qkf.transfer_alignment.scenario.ScenarioData` at once and returns a
:class:`MethodOutput`; ``qkf bench --methods`` picks them by the names in :data:`METHODS`.
"""

from __future__ import annotations

from collections.abc import Callable

from qkf.transfer_alignment.config import Config
from qkf.transfer_alignment.methods.base import MethodOutput
from qkf.transfer_alignment.methods.fixed import run_kf, run_kf_tuned
from qkf.transfer_alignment.methods.mmae import run_mmae
from agents.policy import PREFIX, run_policy
from qkf.transfer_alignment.methods.qlearning import run_qkf
from qkf.transfer_alignment.methods.sage_husa import run_sage_husa
from qkf.transfer_alignment.scenario import ScenarioData

MethodFn = Callable[[Config, ScenarioData], MethodOutput]

METHODS: dict[str, MethodFn] = {
    "kf": run_kf,
    "kf-tuned": run_kf_tuned,
    "sage-husa": run_sage_husa,
    "qkf": run_qkf,
    "mmae": run_mmae,
}
"""Methods available to ``qkf bench --methods``, in their default order."""


def resolve_method(name: str) -> MethodFn:
    """The method called ``name``: a key of :data:`METHODS` or ``policy:PATH``."""
    if name.startswith(PREFIX):
        path = name[len(PREFIX) :]
        return lambda cfg, data: run_policy(cfg, data, path)
    return METHODS[name]


__all__ = ["METHODS", "MethodFn", "MethodOutput", "resolve_method"]
