"""The intruders as a player (docs/model.md section 6): their routing, the drift law as a policy to
the bit, each heuristic against a plain loop of its stated rule, and the settings' refusals."""

import json

import numpy as np
import pytest

from farm.alloc.game.config import AllocConfig
from farm.alloc.game.dynamics import Layout, route_probabilities, routes, routing_of, step
from farm.alloc.game.model import advance_intruders_many, route_intruders_many
from farm.alloc.intruders import intruder_names, make_intruders
from farm.core.config import first_line

SIDES = (2, 3, 5, 8)


def random_state(rng, n, B=6):
    """(D, I): (B, N^2) float64 each, sparse and of mixed sizes, D summing to 1 per episode."""
    D = rng.random((B, n * n)) * (rng.random((B, n * n)) < 0.5)
    D[:, 0] += 1e-3
    D /= D.sum(axis=1, keepdims=True)
    I = rng.random((B, n * n)) * (rng.random((B, n * n)) < 0.6)
    return D, I


def test_the_routes_of_a_grid():
    for n in SIDES:
        src, d_row, start = routes(n)
        assert len(src) == n * (3 * n - 2)
        rows = src // n
        assert set(d_row[rows == 0]) == {0, 1} and set(d_row[rows == n - 1]) == {-1, 0}
        assert np.all((rows + d_row >= 0) & (rows + d_row < n))
        assert np.array_equal(start, np.searchsorted(src, np.arange(n * n)))


@pytest.mark.parametrize("n", SIDES)
@pytest.mark.parametrize("drift", [0.0, 0.1, 0.25, 1 / 3, 0.5])
def test_the_drift_policy_moves_the_intruders_as_the_drift_law_to_the_bit(rng, n, drift):
    config = AllocConfig(grid_size=n, vertical_drift=drift)
    D, I = random_state(rng, n)
    expected = advance_intruders_many(I, n, drift)
    got = route_intruders_many(I, n, *make_intruders("drift", config).routing(D, I))
    assert all(a.tobytes() == b.tobytes() for a, b in zip(expected, got))


def test_a_step_with_the_drift_policy_is_the_default_step_to_the_bit(rng):
    from farm.alloc.game.model import EngagementModel

    class Answers:  # a client: removes a third of every engaged cell, scores one half
        repeatable = True

        def get_many(self, pairs, estimate=False):
            from types import SimpleNamespace
            return [SimpleNamespace(frac_captured_tau=1 / 3, capture_score_tau=0.5, estimate=None) for _ in pairs]

    config = AllocConfig(grid_size=5, vertical_drift=0.25)
    layout, model = Layout(5), EngagementModel(config, Answers())
    D, I = random_state(rng, 5)
    action = rng.uniform(-1, 1, (len(D), len(layout.src)))
    default = step(layout, config, model, D, I, action)
    played = step(layout, config, model, D, I, action, make_intruders("drift", config).routing)
    for name in ("D", "I", "breach", "eliminated", "score", "remaining", "reward"):
        assert getattr(default, name).tobytes() == getattr(played, name).tobytes(), name


@pytest.mark.parametrize("n", SIDES)
def test_any_routing_keeps_the_mass(rng, n):
    D, I = random_state(rng, n)
    layout, config = Layout(n), AllocConfig(grid_size=n)
    p = route_probabilities(layout, config, rng.uniform(-1, 1, (len(I), len(layout.route_src))))
    up, down = routing_of(layout, p)
    rows = np.repeat(np.arange(n), n)
    assert np.all(up[:, rows == 0] == 0) and np.all(down[:, rows == n - 1] == 0)
    assert np.allclose(np.add.reduceat(p, layout.route_start, axis=1), 1.0)
    moved, breach = route_intruders_many(I, n, up, down)
    assert np.allclose(moved.sum(axis=1) + breach, I.sum(axis=1), rtol=0, atol=1e-12)
    assert np.all(moved >= -1e-15)


def slow_route(n, I, up, down):
    """The routing of one episode, mass by mass: (I', breach)."""
    out, breach = np.zeros((n, n)), 0.0
    for r in range(n):
        for c in range(n):
            m = I[r * n + c]
            for dr, share in ((-1, up[r * n + c]), (0, 1 - up[r * n + c] - down[r * n + c]), (1, down[r * n + c])):
                if c == 0:
                    breach += share * m
                elif share:
                    out[r + dr, c - 1] += share * m
    return out.reshape(-1), breach


def test_the_routing_against_a_mass_by_mass_loop(rng):
    for n in SIDES:
        D, I = random_state(rng, n)
        layout = Layout(n)
        p = route_probabilities(layout, AllocConfig(grid_size=n), rng.uniform(-1, 1, (len(I), len(layout.route_src))))
        up, down = routing_of(layout, p)
        moved, breach = route_intruders_many(I, n, up, down)
        for b in range(len(I)):
            want, want_breach = slow_route(n, I[b], up[b], down[b])
            assert np.allclose(moved[b], want, atol=1e-14) and np.isclose(breach[b], want_breach, atol=1e-14)


def ahead(D, n, r, c):
    """The defenders of row r in the columns left of c."""
    return sum(D[r * n + k] for k in range(c))


def pure_routing(n, row_move):
    """The routing (up, down) in which each cell (r, c)'s intruders all move row_move(r, c) rows (-1, 0 or 1)."""
    up, down = np.zeros(n * n), np.zeros(n * n)
    for r in range(n):
        for c in range(n):
            dr = row_move(r, c)
            up[r * n + c], down[r * n + c] = dr == -1, dr == 1
    return up, down


def fewest_ahead_by_hand(n, D):
    def row_move(r, c):
        options = [(ahead(D, n, r + dr, c), order, dr) for order, dr in ((0, 0), (1, -1), (2, 1))
                   if 0 <= r + dr < n]
        return min(options)[2]

    return pure_routing(n, row_move)


def least_defended_by_hand(n, D):
    def row_move(r, c):
        target = min(range(n), key=lambda t: (ahead(D, n, t, c), abs(t - r), t))
        return int(np.sign(target - r))

    return pure_routing(n, row_move)


def split_away_by_hand(n, D):
    up, down = np.zeros(n * n), np.zeros(n * n)
    for r in range(n):
        for c in range(n):
            moves = [dr for dr in (-1, 0, 1) if 0 <= r + dr < n]
            if c == 0:
                continue
            held = {dr: D[(r + dr) * n + c - 1] for dr in moves}
            if max(held.values()) == min(held.values()):
                continue
            keep = [dr for dr in moves if held[dr] < max(held.values())]
            up[r * n + c] = (-1 in keep) / len(keep)
            down[r * n + c] = (1 in keep) / len(keep)
    return up, down


@pytest.mark.parametrize("name, by_hand", [("fewest_ahead", fewest_ahead_by_hand),
                                           ("least_defended", least_defended_by_hand),
                                           ("split_away", split_away_by_hand)])
def test_each_heuristic_follows_its_stated_rule(rng, name, by_hand):
    for n in SIDES:
        policy = make_intruders(name, AllocConfig(grid_size=n))
        D, I = random_state(rng, n)
        D[1] = np.round(D[1] * 4) / 4  # ties
        D[2] = 0.0
        D[2, 0] = 1.0
        up, down = policy.routing(D, I)
        for b in range(len(D)):
            want_up, want_down = by_hand(n, D[b])
            assert np.allclose(up[b], want_up) and np.allclose(down[b], want_down), (name, n, b)


def test_every_registered_policy_routes_a_batch():
    config = AllocConfig(grid_size=3)
    rng = np.random.default_rng(1)
    D, I = random_state(rng, 3)
    for name in intruder_names(("law", "heuristic")):
        up, down = make_intruders(name, config).routing(D, I)
        assert up.shape == down.shape == (len(D), 9) and np.all((up >= 0) & (down >= 0) & (up + down <= 1))


def test_the_intruder_settings_are_written_only_when_set():
    plain = json.loads(AllocConfig().model_dump_json())
    assert not {"intruders", "intruder_options", "information"} & set(plain)
    set_ = AllocConfig(intruders="fewest_ahead", information="simultaneous")
    written = json.loads(set_.model_dump_json())
    assert written["intruders"] == "fewest_ahead" and written["information"] == "simultaneous"
    assert AllocConfig(**written) == set_ and AllocConfig(**plain) == AllocConfig()


@pytest.mark.parametrize("settings, field, words", [
    ({"intruders": "swarmy"}, "intruders", "unknown intruder policy 'swarmy'"),
    ({"intruders": 3}, "intruders", "intruders"),
    ({"information": "telepathic"}, "information", "follower"),
    ({"intruder_options": [1]}, "intruder_options", "intruder_options"),
    # options the policy would not take are refused, not kept and ignored (the drift law takes none)
    ({"intruder_options": {"depth": 2}}, "intruder_options", "drift has no option 'depth' (options: none)"),
    ({"intruders": "fewest_ahead", "intruder_options": {"depth": 2}}, "intruder_options", "no option 'depth'"),
])
def test_a_bad_intruder_setting_is_one_line_naming_its_field(settings, field, words):
    from pydantic import ValidationError

    with pytest.raises(ValidationError) as e:
        AllocConfig(**settings)
    line = first_line(e.value)
    assert line.startswith(f"{field}:") and words in line and "\n" not in line


def test_an_unknown_intruder_option_names_intruder_options():
    from farm.core.errors import ConfigError

    with pytest.raises(ConfigError, match="intruder_options: fewest_ahead has no option 'depth'"):
        make_intruders("fewest_ahead", AllocConfig(), depth=2)
    with pytest.raises(ConfigError, match="intruder_options: learned intruders need the run folder"):
        make_intruders("learned", AllocConfig())


@pytest.mark.parametrize("deterministic", ["false", 0, None])
def test_a_learned_policy_s_deterministic_is_true_or_false_not_a_truthy_value(deterministic, tmp_path):
    from farm.core.errors import ConfigError

    with pytest.raises(ConfigError, match=r"intruder_options.deterministic: must be true or false, got"):
        make_intruders("learned", AllocConfig(), run=str(tmp_path), deterministic=deterministic)
