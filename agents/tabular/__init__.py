"""Tabular Q-learning: the QKF's learner as an episodic agent."""

from agents.tabular.q_learning import TabularQAgent, train_tabular

__all__ = ["TabularQAgent", "train_tabular"]
