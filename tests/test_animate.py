"""Moving pictures: `farm game --animate` (its frame count is the game's steps at the frame
stride, read back from the file), `farm eval RUN --animate` (an episode, and under
`--fidelity games` one engaged cell's game inset), gymnasium's RecordVideo on the env
unchanged (a playable video read back), the report inlining them, and bad flags refused."""

import math

import gymnasium
import numpy as np
import pytest
from conftest import farm_main as farm
from conftest import train_tiny_run
from gymnasium.wrappers import RecordVideo

import farm.alloc as _registers_the_gymnasium_ids  # noqa: F401
from farm.core.game_animation import game_frame_count, game_frame_steps, read_frame_count
from workers import Case, run_games

SMALL = dict(grid_size=3, n_defenders=10, n_intruders=5, games=3)


def test_the_frame_steps_are_every_kth_step_and_the_last():
    assert game_frame_steps(10, 3) == [0, 3, 6, 9, 10]
    assert game_frame_steps(9, 3) == [0, 3, 6, 9]
    assert game_frame_steps(0, 5) == [0]
    for steps in range(0, 40):
        for k in (1, 2, 3, 7, 50):
            shown = game_frame_steps(steps, k)
            assert len(shown) == game_frame_count(steps, k) == math.ceil(steps / k) + 1
            assert shown[0] == 0 and shown[-1] == steps and np.all(np.diff(shown) >= 1)


@pytest.mark.parametrize("suffix, stride", [pytest.param(".gif", 7, marks=pytest.mark.slow), (".mp4", 25)])
def test_farm_game_animates_one_frame_per_kth_step_of_the_game(tmp_path, suffix, stride):
    path = tmp_path / f"g{suffix}"
    status, out, err = farm("game", "--n-pursuers", 5, "--n-evaders", 1, "--seed", 1, "--animate", path,
                            "--frame-stride", stride)
    assert status == 0, err
    case = Case(n_pursuers=5, n_evaders=1)
    steps = int(run_games(case, 1, 0, 1).steps[0])  # the same game, played again by the library
    expected = game_frame_count(steps, stride)
    assert f"({expected} frames, every {stride} step(s) of {steps})" in out
    assert read_frame_count(path) == expected  # decoded back from the file
    assert not list(tmp_path.glob(".*partial*"))


def test_farm_game_refuses_bad_animation_flags_in_one_line(tmp_path):
    for argv, fragment in [(["--animate", tmp_path / "g.png"], "--animate: "),
                           (["--frame-stride", 3], "--frame-stride: is for the animation"),
                           (["--animate", tmp_path / "g.gif", "--frame-stride", 0], "--frame-stride: must be"),
                           (["--animate", tmp_path / "g.gif", "--fps", 500], "--fps: must be between")]:
        status, out, err = farm("game", "--n-pursuers", 2, *argv)
        assert status != 0 and len(err.strip().splitlines()) == 1 and fragment in err, err
    assert not list(tmp_path.iterdir())


def test_record_video_writes_a_playable_video_of_an_episode(tmp_path):
    env = gymnasium.make("farm/SwarmAllocation-v0", render_mode="rgb_array",
                         store=str(tmp_path / "store.sqlite"), **SMALL)
    env = RecordVideo(env, video_folder=str(tmp_path / "videos"), episode_trigger=lambda e: True,
                      disable_logger=True)
    env.reset(seed=3)
    rng = np.random.default_rng(0)
    steps, done = 0, False
    while not done:
        _, _, terminated, truncated, _ = env.step(rng.uniform(-1, 1, env.action_space.shape).astype(np.float32))
        steps += 1
        done = terminated or truncated
    env.close()
    videos = sorted((tmp_path / "videos").glob("*.mp4"))
    assert len(videos) == 1
    import imageio.v3 as iio

    frames = list(iio.imiter(videos[0], plugin="FFMPEG"))
    assert len(frames) == steps + 1  # the reset's frame and one a step
    assert frames[0].shape == (96, 96, 3)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    return train_tiny_run(tmp_path_factory.mktemp("anim"), "eval: {freq: 120, episodes: 2}\n")


@pytest.mark.slow
def test_farm_eval_animates_an_episode_and_the_report_inlines_it(run):
    from farm.alloc.evaluation.animation import episode_frame_count
    from farm.alloc.evaluation.rollout import Episode

    status, out, err = farm("eval", run, "--episodes", 2, "--references", "none", "--animate")
    assert status == 0, err
    path = run / "episode.gif"
    frames = read_frame_count(path)
    length = int(__import__("pandas").read_csv(run / "eval_episodes.csv")["length"].iloc[0])
    assert frames == length + 1 == episode_frame_count(Episode({}, None, [None] * (length + 1), 0.0, None))
    assert f"animation: {path} ({frames} frames)" in out

    status, out, err = farm("eval", run, "--episodes", 2, "--references", "none", "--fidelity", "games",
                            "--animate", "games.mp4")
    assert status == 0, err
    assert (run / "games.mp4").exists() and read_frame_count(run / "games.mp4") > frames  # the inset game plays

    from farm.report import build_report

    page = build_report(run)
    assert page.count("data:image/gif;base64,") == 1 and page.count("data:video/mp4;base64,") == 1
    assert "episode.gif" in page and "games.mp4" in page


def test_the_inset_is_the_first_engagement_played_as_a_fresh_game():
    from farm.alloc.evaluation.animation import episode_frame_steps, inset_game
    from farm.alloc.evaluation.rollout import Episode
    from farm.service import GameSettings

    empty = np.zeros(0, dtype=np.int64)
    frames = [(np.zeros((3, 3)), np.zeros((3, 3)))] * 4
    engaged = [(empty, empty, empty), (np.array([1, 4]), np.array([3, 2]), np.array([1, 2])), (empty, empty, empty)]
    episode = Episode({}, None, frames, 0.0, None, engaged)
    settings = GameSettings.of(games=3, t_max=15.0)
    inset = inset_game(episode, settings)
    assert (inset.step, inset.cell, inset.n_p, inset.n_e) == (2, 4, 2, 2)  # the cell with the most evaders
    key = settings.key(2, 2)
    again = run_games(key.case, key.seed, settings.games, settings.games + 1)  # the service's first unseen game
    np.testing.assert_array_equal(inset.res.capture_times, again.capture_times)
    shown = episode_frame_steps(episode, inset)
    assert [t for t, _ in shown] == [0, 1] + [2] * len(inset.frames) + [3]
    assert shown[0][1] is None and shown[-1][1] == inset.frames[-1]
    assert inset_game(Episode({}, None, frames, 0.0, None, [(empty, empty, empty)] * 3), settings) is None
