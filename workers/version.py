"""The engine's version: part of every Case, so a changed engine never mixes its numbers
with an older one's.

In a module of its own, importing nothing, so that both the game model (workers.case)
and the engine (workers.engine) can name it without importing each other.
"""

__all__ = ["ENGINE_VERSION"]

ENGINE_VERSION = "2.0.0"
