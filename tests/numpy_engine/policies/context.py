"""What the policies of one step see: the state of the running games and the
geometry derived from it, each piece computed once and only when asked for."""

from __future__ import annotations

from functools import cached_property

import numpy as np

from numpy_engine.geometry import NEIGHBOUR_EDGE_MIN, PAD, voronoi_cells
from workers.arena import Arena

HEADING_MIN = 1e-12


def unit_velocity(goal: np.ndarray, position: np.ndarray, v_max: float) -> np.ndarray:
    """Velocity of speed v_max from position towards goal, zero when closer than 1e-12.

    goal, position: (..., 2) float64 -> (..., 2) float64.
    """
    h = goal - position
    norm = np.hypot(h[..., 0], h[..., 1])
    scale = np.where(norm >= HEADING_MIN, v_max / np.where(norm >= HEADING_MIN, norm, 1.0), 0.0)
    return h * scale[..., None]


def pursuer_evader_distance(pursuers, evaders, alive) -> np.ndarray:
    """pursuers (A, n_p, 2), evaders (A, n_e, 2), alive (A, n_e) -> (A, n_p, n_e) float64, inf if captured."""
    dx = pursuers[:, :, None, 0] - evaders[:, None, :, 0]
    dy = pursuers[:, :, None, 1] - evaders[:, None, :, 1]
    return np.where(alive[:, None, :], np.hypot(dx, dy), np.inf)


class StepContext:
    """State of A running games at one step.

    pursuers: (A, n_p, 2) float64; evaders: (A, n_e, 2) float64; alive: (A, n_e)
    bool (live evaders); target: (2,) float64 goal of `target` evaders;
    distance: optional precomputed `distance`; hint: optional (A, n_e, H) int64
    labels of each evader's cell at the last step (warm start, see geometry).
    cell_labels: None until a policy builds the cells, then (A, n_e, M) int64 this step's
    labels (the engine's warm start for the next step).
    """

    def __init__(
        self, pursuers, evaders, alive, *, arena: Arena, dt: float, v_max: float, target, distance=None,
        hint=None,
    ):
        if distance is not None:
            self.distance = distance
        self.hint = hint
        self.cell_labels: np.ndarray | None = None
        self.pursuers = pursuers
        self.evaders = evaders
        self.alive = alive
        self.arena = arena
        self.dt = dt
        self.v_max = v_max
        self.target = np.asarray(target, dtype=np.float64)

    @property
    def n_games(self) -> int:
        return self.pursuers.shape[0]

    @cached_property
    def distance(self) -> np.ndarray:
        """(A, n_p, n_e) float64 pursuer-evader distances, inf for captured evaders."""
        return pursuer_evader_distance(self.pursuers, self.evaders, self.alive)

    @cached_property
    def _evader_cells(self):
        a, n_p, n_e = self.n_games, self.pursuers.shape[1], self.evaders.shape[1]
        points = np.concatenate([self.pursuers, self.evaders], axis=1)
        live = np.concatenate([np.ones((a, n_p), dtype=bool), self.alive], axis=1)
        game, evader = np.nonzero(self.alive)
        hint = None if self.hint is None else self.hint[game, evader]
        cells = voronoi_cells(points, live, game, n_p + evader, self.arena, hint=hint)
        self.cell_labels = np.full((a, n_e, cells.labels.shape[1]), PAD, dtype=np.int64)
        self.cell_labels[game, evader] = cells.labels
        area, centroid = cells.area_centroid()
        length, mid = cells.edges()

        shared_length = np.zeros((a, n_e, n_p))
        shared_mid = np.zeros((a, n_e, n_p, 2))
        c, slot = np.nonzero((cells.labels >= 0) & (cells.labels < n_p) & (length > NEIGHBOUR_EDGE_MIN))
        j = cells.labels[c, slot]
        shared_length[game[c], evader[c], j] = length[c, slot]
        shared_mid[game[c], evader[c], j] = mid[c, slot]

        cell_area = np.zeros((a, n_e))
        cell_centroid = self.evaders.copy()
        cell_area[game, evader] = area
        cell_centroid[game, evader] = centroid
        return shared_length, shared_mid, cell_area, cell_centroid

    @property
    def shared_length(self) -> np.ndarray:
        """(A, n_e, n_p) float64 length of the edge evader i shares with pursuer j, 0 if none."""
        return self._evader_cells[0]

    @property
    def shared_midpoint(self) -> np.ndarray:
        """(A, n_e, n_p, 2) float64 midpoint C_b of that edge (meaningless where length is 0)."""
        return self._evader_cells[1]

    @property
    def neighbours(self) -> np.ndarray:
        """(A, n_e, n_p) bool: live evader i and pursuer j share an edge longer than 1e-9."""
        return self.shared_length > NEIGHBOUR_EDGE_MIN

    @property
    def cell_area(self) -> np.ndarray:
        """(A, n_e) float64 area of each live evader's cell (0 for captured evaders)."""
        return self._evader_cells[2]

    @property
    def cell_centroid(self) -> np.ndarray:
        """(A, n_e, 2) float64 centroid of each live evader's cell (own position if captured)."""
        return self._evader_cells[3]
