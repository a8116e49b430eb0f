"""Evaluation: the one rollout loop (rollout.py), fidelity games (fidelity.py), episode animations
(animation.py) and a run folder's evaluation, `farm eval` (evaluate.py)."""
