"""Trajectories, sensor error models and simulated devices."""
