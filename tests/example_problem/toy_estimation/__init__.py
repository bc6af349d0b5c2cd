"""Toy problem: a scalar random walk ``x`` (unit u) read with white noise every ``dt_s`` and
estimated by a Kalman filter. The shape of every qkf problem package (docs/architecture.md,
"Problem shape"): config, scenario, estimator, benchmark on the core runner, report, cli."""
