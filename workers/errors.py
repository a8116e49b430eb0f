"""The one exception type for bad input to the engine and the Monte Carlo layer."""

__all__ = ["InputError"]


class InputError(ValueError):
    """Bad input: the message is one line that names the argument and the problem."""
