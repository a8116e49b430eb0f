"""Trained networks: stable-baselines3 models loaded and checked (trained.py) and the cell policy,
one network for every map size (cell_policy.py); used by the learned allocators, the learned
intruders and training alike."""
