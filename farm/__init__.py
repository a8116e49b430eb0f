"""swarm-farm's control plane: CLI, reports, and (later) the Ray farm, the
capture-time service and the allocation trainer. Imports `workers`, never the reverse."""

from workers import ENGINE_VERSION

__all__ = ["ENGINE_VERSION"]
