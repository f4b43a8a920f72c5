"""Learners: the recurrent actor-critic network and the PPO agents built on it."""
