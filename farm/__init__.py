"""swarm-farm's control plane: config loading, the `farm` CLI, sweeps on Ray, the
capture-time service, the allocation env and its TD3 trainer, figures and the report.
Imports `workers`, never the reverse; importing it changes no process-wide setting."""

from workers import ENGINE_VERSION

__all__ = ["ENGINE_VERSION"]
