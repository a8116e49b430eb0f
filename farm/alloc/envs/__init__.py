"""The game as environments: the defenders' gymnasium env (defenders.py) and its batched form
(vector.py), the intruders' env against a frozen allocator (intruders.py), the two-player
PettingZoo envs (pettingzoo_env.py), the SB3 vector adapter (sb3_vec.py) and the move helpers
that answer a planner's moves on Ray (move_helpers.py)."""
