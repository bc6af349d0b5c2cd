"""Agents that choose the filter's process-noise scale κ through the environments of :mod:`envs`.

The algorithms by name (:mod:`.algorithms`: tabular Q-learning and the Stable-Baselines3
agents), their training (:mod:`.training`, :mod:`.config`), a saved agent as a benchmark method
(:mod:`.policy`, ``--methods policy:PATH``), the zoo of shipped policies (:mod:`.zoo`) and the
commands ``qkf train``, ``evaluate`` and ``zoo`` (:mod:`.cli`). The baselines an agent is judged
against are its problem's methods (``qkf.core.problem.PROBLEMS``), not policies of this package.
"""
