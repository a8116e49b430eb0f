"""Pursuit-evasion games on the farm: a game's start given by hand (start), coarse shards of
games (shards), the size of a job before it runs (sizes), the Ray task that plays a shard
(tasks), the paper's tables (pe_table) and parametric Monte Carlo sweeps (sweep/)."""
