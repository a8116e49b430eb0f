"""Counts that size memory, frames or actors are checked against what they cost before the work
starts, and a planner setting that would make its arithmetic degenerate is refused or cannot
degenerate: one line naming the field and the cost, in process, no Ray (the Ray a subregions
planner would ask is stood in for).

- `farm game --frame-stride 1` on a long game: refused before the game is shown or any frame
  drawn (and game_frames itself, before any frame).
- The batched envs (`gymnasium.make_vec`, the intruders' vector env) with more episodes than half
  the machine holds: refused before any array.
- The subregions planner with more band actors than the Ray has CPUs (less those its task holds).
- The transport planner with a large power: every unit to the heaviest row, never 0/0;
  min_count and mmr's chunk above the defenders there are: refused.
- A pretraining whose labels would not fit in memory, and a `farm eval` whose tables would not:
  refused before any episode.
"""

import numpy as np
import pytest

from farm.alloc import AllocConfig
from farm.core.errors import ConfigError

from conftest import farm_main, train_tiny_run
from helpers import farm_refusal

LONG_GAME = ("--t-max", "600", "--evader-speed", "3", "--n-pursuers", "1")  # an evader no pursuer catches


class DrewAFrame(Exception):
    """Raised by the stand-in of figure_frames: a frame was about to be drawn."""


@pytest.fixture
def no_frames(monkeypatch):
    """Drawing a frame fails the test at once (instead of drawing thousands)."""
    import farm.core.game_animation as animation

    def refuse(fig, draw, items):
        raise DrewAFrame()
        yield  # a generator, as figure_frames is

    monkeypatch.setattr(animation, "figure_frames", refuse)


def test_farm_game_refuses_more_frames_than_fit_before_the_game_is_shown(tmp_path, no_frames):
    status, out, err = farm_main("game", "--animate", tmp_path / "g.gif", "--frame-stride", "1", *LONG_GAME)
    farm_refusal(status, err, "--frame-stride: 60,001 frames of 400 x 416 pixels need 27.9 GiB in memory to encode, "
                              "more than 1 GiB; a frame stride of at least 28 fits")
    assert out == "" and not (tmp_path / "g.gif").exists()


def test_game_frames_refuses_before_any_frame(no_frames):
    from workers import Case, simulate_case

    from farm.core.game_animation import game_frames

    case = Case(1, 1, evader_speed=3.0, t_max=600.0)
    p, e = np.array([[[1.0, 1.0]]]), np.array([[[9.0, 9.0]]])
    res = simulate_case(case, p, e, record=True)
    assert int(res.steps[0]) == 60_000
    with pytest.raises(ConfigError, match=r"^frame_stride: 60,001 frames"):
        game_frames(res, 0, stride=1)


def test_the_batched_env_refuses_more_episodes_than_memory_holds(tmp_path):
    import gymnasium

    import farm.alloc  # noqa: F401 - registers the envs

    with pytest.raises(ConfigError) as e:
        gymnasium.make_vec("farm/SwarmAllocation-v0", num_envs=10**9, vectorization_mode="vector_entry_point",
                           grid_size=3, n_defenders=10, n_intruders=5, store=str(tmp_path / "s.sqlite"))
    assert e.value.field == "num_envs" and "\n" not in str(e.value)
    assert str(e.value).startswith("num_envs: 1,000,000,000 episodes of a 3 x 3 grid need about ")
    assert "GiB in memory, more than half of this machine's" in str(e.value)


def test_the_intruders_batched_env_refuses_more_episodes_than_memory_holds(tmp_path):
    from farm.alloc.envs.intruders import SwarmIntruderVectorEnv

    with pytest.raises(ConfigError, match=r"^num_envs: 1,000,000,000 episodes of a 3 x 3 grid need about"):
        SwarmIntruderVectorEnv(AllocConfig(grid_size=3, n_defenders=10, n_intruders=5), num_envs=10**9,
                               store=str(tmp_path / "s.sqlite"))


@pytest.fixture
def ray_of(monkeypatch):
    """Stand in for a running Ray of `cpus` CPUs, this process holding `held` of them."""
    import ray

    def stand_in(cpus: float, held: float = 0.0):
        class Context:
            def get_assigned_resources(self):
                return {"CPU": held} if held else {}

        monkeypatch.setattr(ray, "is_initialized", lambda: True)
        monkeypatch.setattr(ray, "cluster_resources", lambda: {"CPU": cpus})
        monkeypatch.setattr(ray, "get_runtime_context", lambda: Context())

    return stand_in


def test_subregions_refuses_band_actors_a_ray_can_never_start(ray_of):
    from farm.alloc.allocators import make_allocator

    ray_of(2.0)
    cfg = AllocConfig(grid_size=4, n_defenders=10, n_intruders=50)
    with pytest.raises(ConfigError) as e:
        make_allocator("subregions", cfg, None, regions=4, planner="intercept", workers=64)
    assert str(e.value) == ("subregions: workers: 64 starts 4 band actors of one CPU each, which can never all run: "
                            "the Ray this process is connected to has 2 CPUs; set workers <= 2")
    ray_of(2.0, held=1.0)  # inside a task that holds one of them
    with pytest.raises(ConfigError, match="has 2 CPUs and this task holds 1 of them; set workers <= 1"):
        make_allocator("subregions", cfg, None, regions=4, planner="intercept", workers=2)
    ray_of(2.0)
    make_allocator("subregions", cfg, None, regions=2, planner="intercept", workers=64)  # one actor a band: 2 fit


def test_transport_with_a_large_power_sends_every_unit_to_the_heaviest_row():
    """Two intruder rows of masses 3:1 on 16 x 16: power 1 splits the 8 defenders 6:2; power 1000
    gives them all to the heavier row (its weight relative to the heaviest row's is 1), where
    the masses raised to 1000 underflow to 0/0."""
    from farm.alloc.allocators.planners import Intercept, Transport

    n = 16
    cfg = AllocConfig(grid_size=n, n_defenders=8, n_intruders=1600, max_steps=n, team_sizes="lattice")
    D, I = np.zeros(n * n), np.zeros(n * n)
    D[8 * n] = 1.0
    I[n - 1], I[n * n - 1] = 0.3, 0.1
    for power, up_share in ((1.0, 6 / 8), (1000.0, 1.0)):
        planner = Transport(cfg, power=power)
        src, dst = planner.src, planner.dst
        p = planner.probabilities(D, I)
        assert np.all(np.isfinite(p))
        moved = np.bincount(dst, weights=p * D[src], minlength=n * n)
        assert moved[7 * n + 1] == pytest.approx(up_share)
    assert not np.allclose(Transport(cfg, power=1000.0).probabilities(D, I), Intercept(cfg).probabilities(D, I))


@pytest.mark.parametrize("name, options, message", [
    ("transport", {"min_count": 11}, "transport: min_count 11 is more than the 10 defenders there are"),
    ("mmr", {"chunk": 12.5}, "mmr: chunk 12.5 is more than the 10 defenders there are"),
])
def test_a_setting_that_leaves_a_planner_nothing_to_plan_is_refused(tmp_path, name, options, message):
    from farm.alloc.allocators import make_allocator
    from farm.service import CaptureTimeClient

    cfg = AllocConfig(grid_size=3, n_defenders=10, n_intruders=5)
    client = CaptureTimeClient(cfg.game_settings(), local_store=tmp_path / "s.sqlite")
    with pytest.raises(ConfigError) as e:
        make_allocator(name, cfg, client, **options)
    assert str(e.value).startswith(message) and "it would act as intercept" in str(e.value)


class Labelled(Exception):
    """Raised by the stand-in of label_all: an episode was about to be labelled."""


def test_a_pretraining_whose_labels_do_not_fit_is_refused_before_any_episode(tmp_path, monkeypatch):
    import farm.alloc.training.dagger.loop as loop

    def refuse(*args, **kwargs):
        raise Labelled()

    monkeypatch.setattr(loop, "label_all", refuse)
    config = tmp_path / "t.yaml"
    config.write_text("name: t\nenv: {grid_size: 3, n_defenders: 10, n_intruders: 5, games: 3}\n"
                      "td3: {n_timesteps: 200, learning_starts: 50}\n"
                      f"service: {{mode: local, store: {tmp_path / 's.sqlite'}}}\n"
                      "pretrain: {expert: intercept, iterations: 1000, episodes: 100000000}\n")
    status, out, err = farm_main("train", config, "--out", tmp_path / "run")
    farm_refusal(status, err, f"{config}: pretrain.episodes: 1000 iterations of 100,000,000 episodes on 1 map(s) "
                              "label up to ", "GiB, more than half of this machine's memory")
    assert not (tmp_path / "run").exists()


def test_farm_eval_refuses_more_episodes_than_its_tables_fit_before_any_episode(tmp_path, monkeypatch):
    import farm.alloc.evaluation.evaluate as evaluation

    def refuse(*args, **kwargs):
        raise Labelled()  # an episode was about to be played

    monkeypatch.setattr(evaluation, "evaluate_trained", refuse)
    run = train_tiny_run(tmp_path)
    status, out, err = farm_main("eval", run, "--episodes", 10**12, "--references", "none")
    farm_refusal(status, err, "--episodes: 1,000,000,000,000 episodes of 1 allocators keep up to ",
                 "GiB of tables in memory, more than half of this machine's")
    assert not (run / "eval_table.csv").exists()
