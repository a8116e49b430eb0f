"""The bounded convex arena: validation, containment and projection."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from workers.errors import InputError, all_numbers, not_a_number_hint

__all__ = ["Arena", "DEFAULT_ARENA", "make_arena"]

_INSIDE_TOL = 1e-9
# An arena whose area is below this fraction of its bounding box's diagonal squared is
# refused as degenerate. The ratio does not depend on the arena's scale or units (a
# rectangle L x w gives about w / L), and 1e-9 refuses only slivers thinner than a
# billionth of their length: no game fits in one (agents are 1e-9 apart from its other
# side, the containment tolerance _INSIDE_TOL for a 1-unit arena), and three almost
# collinear vertices, whose round-off decides the normals, are among them.
_MIN_AREA_RATIO = 1e-9


@dataclass(frozen=True, eq=False)
class Arena:
    """A convex polygon, vertices counter-clockwise.

    vertices: (k, 2) float64; normals: (k, 2) float64 outward unit normal of edge
    i (from vertex i to vertex i+1); offsets: (k,) float64, so that a point x is
    inside when normals @ x <= offsets.
    """

    vertices: np.ndarray
    normals: np.ndarray
    offsets: np.ndarray

    def __post_init__(self):
        box = (self.vertices.min(axis=0), self.vertices.max(axis=0)) if self.is_axis_box else None
        object.__setattr__(self, "_box", box)

    @property
    def k(self) -> int:
        """The number of vertices (and edges)."""
        return len(self.vertices)

    @property
    def area(self) -> float:
        """The polygon's area (shoelace formula)."""
        v = self.vertices
        w = np.roll(v, -1, axis=0)
        return 0.5 * float(np.sum(v[:, 0] * w[:, 1] - w[:, 0] * v[:, 1]))

    def signed_distances(self, points: np.ndarray) -> np.ndarray:
        """points: (..., 2) float64 -> (..., k) float64, positive outside edge i."""
        return (
            points[..., None, 0] * self.normals[:, 0]
            + points[..., None, 1] * self.normals[:, 1]
            - self.offsets
        )

    def contains(self, points: np.ndarray, tol: float = _INSIDE_TOL) -> np.ndarray:
        """points: (..., 2) float64 -> (...) bool, True inside or on the boundary."""
        return np.all(self.signed_distances(points) <= tol, axis=-1)

    @property
    def is_axis_box(self) -> bool:
        """True for an axis-aligned rectangle, where projection is a clip."""
        return self.k == 4 and bool(np.all(np.abs(self.normals) % 1.0 == 0.0))

    def project(self, points: np.ndarray) -> np.ndarray:
        """Nearest point of the arena. points: (..., 2) float64 -> (..., 2) float64."""
        if self._box is not None:
            return np.clip(points, self._box[0], self._box[1])
        outside = ~self.contains(points, tol=0.0)
        if not outside.any():
            return points
        out = points.copy()
        p = points[outside]  # (m, 2)
        a = self.vertices  # (k, 2)
        ab = np.roll(a, -1, axis=0) - a  # (k, 2)
        t = ((p[:, None, 0] - a[:, 0]) * ab[:, 0] + (p[:, None, 1] - a[:, 1]) * ab[:, 1]) / (
            ab[:, 0] ** 2 + ab[:, 1] ** 2
        )
        t = np.clip(t, 0.0, 1.0)  # (m, k)
        foot = a + t[..., None] * ab  # (m, k, 2)
        d2 = (foot[..., 0] - p[:, None, 0]) ** 2 + (foot[..., 1] - p[:, None, 1]) ** 2
        best = np.argmin(d2, axis=1)
        out[outside] = foot[np.arange(len(p)), best]
        return out

    def sample_uniform(self, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
        """Uniform points in the arena by rejection from its bounding box: shape + (2,) float64."""
        lo = self.vertices.min(axis=0)
        hi = self.vertices.max(axis=0)
        n = int(np.prod(shape))
        out = np.empty((0, 2))
        while len(out) < n:
            need = n - len(out)
            cand = lo + (hi - lo) * rng.random((max(2 * need, 16), 2))
            out = np.concatenate([out, cand[self.contains(cand, tol=0.0)]])
        return out[:n].reshape(*shape, 2)


def make_arena(vertices=None) -> Arena:
    """Validate a convex polygon and return an Arena (None gives the square [0, 10]^2).

    vertices: (k, 2) array-like, k >= 3, in either orientation; collinear vertices
    are rejected, as are repeated ones, non-convex or self-intersecting polygons and
    near-degenerate ones (area below 1e-9 x the bounding box's diagonal squared); every
    coordinate must be a number (not a bool). A bad polygon raises InputError naming arena.
    """
    if vertices is None:
        return DEFAULT_ARENA
    if isinstance(vertices, Arena):
        return vertices
    try:
        if not all_numbers(vertices):
            raise TypeError
        v = np.array(vertices, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise InputError(f"arena: vertices must be numbers of shape (k, 2){not_a_number_hint(vertices)}",
                         field="arena") from None
    if v.ndim != 2 or v.shape[1] != 2 or v.shape[0] < 3:
        raise InputError(f"arena: vertices must have shape (k, 2) with k >= 3, got {v.shape}", field="arena")
    if not np.all(np.isfinite(v)):
        raise InputError("arena: vertices must be finite", field="arena")
    w = np.roll(v, -1, axis=0)
    with np.errstate(over="ignore", invalid="ignore"):
        signed_area = 0.5 * float(np.sum(v[:, 0] * w[:, 1] - w[:, 0] * v[:, 1]))
        diagonal2 = float(np.sum((v.max(axis=0) - v.min(axis=0)) ** 2))
    if not (math.isfinite(signed_area) and math.isfinite(diagonal2)):
        raise InputError("arena: vertices are too large (the polygon's area overflows a float)", field="arena")
    scale = float(np.max(np.abs(v))) or 1.0
    if not abs(signed_area) > _MIN_AREA_RATIO * diagonal2:
        raise InputError(f"arena: polygon is degenerate (area {abs(signed_area):.3g} is below "
                         f"{_MIN_AREA_RATIO:g} x its bounding box's diagonal squared, {diagonal2:.3g})", field="arena")
    if signed_area < 0:
        v = v[::-1].copy()
    e = np.roll(v, -1, axis=0) - v
    lengths = np.hypot(e[:, 0], e[:, 1])
    if np.any(lengths <= 1e-12 * scale):
        raise InputError("arena: polygon has repeated vertices", field="arena")
    e_next = np.roll(e, -1, axis=0)
    turn = (e[:, 0] * e_next[:, 1] - e[:, 1] * e_next[:, 0]) / (lengths * np.roll(lengths, -1))
    if np.any(turn <= 1e-12):
        raise InputError("arena: polygon must be strictly convex (no reflex or collinear vertices)", field="arena")
    # A star polygon turns left everywhere yet winds more than once.
    total_turn = np.sum(np.arctan2(turn, (e * e_next).sum(axis=1) / (lengths * np.roll(lengths, -1))))
    if total_turn > 2 * np.pi + 1e-6:
        raise InputError("arena: polygon is self-intersecting", field="arena")
    normals = np.stack([e[:, 1], -e[:, 0]], axis=1) / lengths[:, None]
    offsets = normals[:, 0] * v[:, 0] + normals[:, 1] * v[:, 1]
    for a in (v, normals, offsets):
        a.setflags(write=False)
    return Arena(v, normals, offsets)


def _square(size: float) -> Arena:
    v = np.array([[0.0, 0.0], [size, 0.0], [size, size], [0.0, size]])
    n = np.array([[0.0, -1.0], [1.0, 0.0], [0.0, 1.0], [-1.0, 0.0]])
    o = np.array([0.0, size, size, 0.0])
    for a in (v, n, o):
        a.setflags(write=False)
    return Arena(v, n, o)


DEFAULT_ARENA = _square(10.0)
