"""Agents that choose the filter's process-noise scale: tabular Q-learning, SB3 agents and
baseline policies. Populated by the environments-and-agents issue."""
