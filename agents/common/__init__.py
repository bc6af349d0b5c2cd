"""What the agents' runners share: the vectorised training and evaluation environments of a
training config, built from the environment registry, and the learner's reward scale
(:mod:`agents.common.vec_env`)."""
