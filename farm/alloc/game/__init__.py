"""The game: the map's config (config.py), the engagement model (model.py), one step's dynamics
(dynamics.py), the measures (measures.py), the named scenarios (scenarios.py), the lattice of
warmed states (lattice.py), plots of the game (plots.py), and the two sides' registries
(registry.py)."""
