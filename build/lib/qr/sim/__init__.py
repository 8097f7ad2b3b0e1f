"""Simulation: the rigid-body plant, controllers, trajectories, synthetic flights, the study."""
