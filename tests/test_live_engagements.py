"""`farm eval --fidelity games` on a theatre: every engaged cell's game played live, a step's
games of every episode packed into coarse Ray tasks; the same games, outcome for outcome, as
the engine run in this process."""

import numpy as np
import pandas as pd
import pytest

from farm.alloc.game.scenarios import SCENARIOS

pytestmark = pytest.mark.ray


@pytest.mark.slow
def test_a_theatre_episode_plays_the_same_games_on_ray_as_in_process(ray_local, tmp_path):
    from farm.alloc.allocators import make_allocator
    from farm.alloc.evaluation.fidelity import evaluate_fidelity
    from farm.service import CaptureTimeClient
    from workers import run_games

    config = SCENARIOS["theatre_16x16"].config(games=2)
    client = CaptureTimeClient(config.game_settings(), local_store=tmp_path / "s.sqlite")
    policies = {name: make_allocator(name, config, client) for name in ("intercept", "receding_horizon")}
    ray_table, ray_games, live = evaluate_fidelity(config, policies, client, 1, 1000)
    here_table, here_games, here = evaluate_fidelity(config, policies, client, 1, 1000, in_process=True)
    pd.testing.assert_frame_equal(ray_table, here_table)
    pd.testing.assert_frame_equal(ray_games, here_games)
    assert len(ray_games) == live["games"] == here["games"] > 30 and here["tasks"] == 0
    assert 1 <= live["tasks"] < live["games"] / 5  # coarse: many games a task
    for row in ray_games.iloc[[0, len(ray_games) // 2, -1]].itertuples():  # the engine, game for game
        key = config.game_settings().key(row.n_pursuers, row.n_evaders)
        np.testing.assert_array_equal(run_games(key.case, key.seed, row.game, row.game + 1).capture_times[0],
                                      np.array(row.capture_times))


def test_subregions_on_ray_actors_plan_what_they_plan_in_process(ray_local, tmp_path):
    """subregions' bands planned on 2 Ray actors (each opening the local store) give the same
    move probabilities as the bands planned one after another here."""
    from farm.alloc import AllocConfig
    from farm.alloc.allocators import make_allocator
    from farm.service import CaptureTimeClient

    config = AllocConfig(grid_size=6, n_defenders=24, n_intruders=40, games=2, team_sizes="lattice")
    client = CaptureTimeClient(config.game_settings(), local_store=tmp_path / "s.sqlite")
    rng = np.random.default_rng(3)
    D = rng.dirichlet(np.ones(36))
    I = np.where(rng.random(36) < 0.5, rng.random(36) * 0.05, 0.0)
    here = make_allocator("subregions", config, client, regions=3).probabilities(D, I)
    planner = make_allocator("subregions", config, client, regions=3, workers=2)
    try:
        np.testing.assert_allclose(planner.probabilities(D, I), here, atol=1e-12)
    finally:
        planner.close()
        client.close()


@pytest.mark.own_ray
@pytest.mark.slow
def test_subregions_band_actors_without_a_running_ray_start_the_runtimes_own_ray(tmp_path):
    """With no Ray running, subregions' band actors start Ray through farm.runtime (a local Ray of
    its own, in the project's namespace, stopped with the planner), never by Ray's own defaults
    (which would join a `ray start` cluster or its stale pointer file on this machine)."""
    import os
    import subprocess
    import sys
    import textwrap

    from conftest import ray_start_lock

    script = textwrap.dedent(f"""
        import numpy as np, ray
        from farm.alloc import AllocConfig
        from farm.alloc.allocators import make_allocator
        from farm.service import CaptureTimeClient
        config = AllocConfig(grid_size=6, n_defenders=24, n_intruders=40, games=2, team_sizes="lattice")
        client = CaptureTimeClient(config.game_settings(), local_store={str(tmp_path / 's.sqlite')!r})
        planner = make_allocator("subregions", config, client, regions=3, planner="intercept", workers=2)
        p = planner.probabilities(np.full(36, 1 / 36), np.full(36, 0.01))
        print(ray.get_runtime_context().namespace, int(ray.cluster_resources()["CPU"]), bool(np.isfinite(p).all()))
        planner.close()
        print(ray.is_initialized())
    """)
    env = {k: v for k, v in os.environ.items() if k not in ("RAY_ADDRESS", "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER")}
    with ray_start_lock():
        out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.split() == ["swarm-farm", "2", "True", "False"]
