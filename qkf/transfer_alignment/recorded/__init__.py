"""Recorded transfer-alignment data: telemetry or test-bench runs as the trials of a benchmark
(docs/recorded_data.md).

``columns`` and ``reader`` / ``writer``: the file format (CSV or Parquet, one row per epoch);
``grid``: rows → the filter's uniform time grid (a
:class:`~qkf.transfer_alignment.scenario.ScenarioData`);
``run``: every method on it; ``quality``: the truth-free measures (NIS bands, whiteness);
``outputs``: the run folder (``estimates.csv``, ``quality.csv``, ``summary.md``, plots).
"""
