import numpy as np
import pytest

SQUARE = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]])
HEXAGON = np.array([[5 + 5 * np.cos(a), 5 + 5 * np.sin(a)] for a in np.arange(6) * np.pi / 3])
TRIANGLE = np.array([[0.0, 0.0], [10.0, 0.0], [3.0, 8.0]])


def points_in(arena_vertices, shape, rng):
    from workers import make_arena

    return make_arena(arena_vertices).sample_uniform(rng, shape)


@pytest.fixture
def rng():
    return np.random.default_rng(20261123)
