"""Studies built on allocation: the scenario suite (suite/), experiments over grids and seeds
as Ray Tune trials (experiments/, their folders experiment_folder.py) and the paper's claims
measured on their runs (claims.py)."""
