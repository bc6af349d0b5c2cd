"""Tabular Q-learning: the QKF's learner as an episodic agent."""

from agents.tabular.q_learning import TabularQAgent

__all__ = ["TabularQAgent"]
