"""The zoo of trained policies: ``agents/zoo/<name>/`` per shipped policy (docs/zoo.md).

An entry is a folder with ``zoo.yaml`` (what to train and how to judge it), the training config
it names, and what ``qkf zoo train`` and ``qkf zoo evaluate`` write into it:

* ``seed_<s>/``: per training seed, ``model.zip`` (or ``model.npz``), ``config.yaml``,
  ``training.json`` and ``evaluations.npz`` (the periodic evaluations on the held-out
  environment seed ``eval.seed``; checkpoints and logs stay in the work folder);
* ``model.*`` and ``config.yaml``: the training seed with the best last evaluation on
  ``eval.seed`` (chosen without the judging seeds);
* ``card.md``: the model card (command, seeds, reward, wall time, evaluation tables);
* ``evaluation/``: the judging tables (``trials.csv`` of every benchmark, ``zoo_summary.csv``).

``agents/zoo/best/`` holds a copy of the best transfer-alignment entry (``qkf zoo promote
NAME``), so that ``qkf bench … --methods …,policy:agents/zoo/best/model.zip`` works without
knowing its name; the best entry of another problem goes to ``agents/zoo/best_<problem>/``.
"""

from agents.zoo.entry import ZOO_DIR, ZooEntry, list_entries, load_entry

__all__ = ["ZOO_DIR", "ZooEntry", "list_entries", "load_entry"]
