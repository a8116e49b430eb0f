"""The kinds of error `farm` reports in one line (`farm: error: ...`, exit 2).

All are workers.SwarmFarmError, as is workers.InputError (bad input to the engine
or a Case); the CLI catches that one base class.
"""

from workers.errors import InputError, SwarmFarmError

__all__ = ["SwarmFarmError", "InputError", "ConfigError", "ClusterError", "SweepError", "StoreCorruptError",
           "NotAStoreError", "ReportError", "ResultsError", "CliError", "ActionError", "TrainingDiverged", "ModelError",
           "StorageError"]


class ConfigError(SwarmFarmError, ValueError):
    """A bad config file or field: names the file, the field and the problem."""


class ClusterError(SwarmFarmError):
    """No Ray cluster answers at the address given."""


class SweepError(SwarmFarmError):
    """A sweep that cannot go on."""


class StoreCorruptError(SwarmFarmError):
    """The capture-time store's file is damaged."""


class NotAStoreError(SwarmFarmError):
    """A sound SQLite file that is not a capture-time store."""


class ReportError(SwarmFarmError, ValueError):
    """A results folder the report cannot be made from."""


class ResultsError(SwarmFarmError, ValueError):
    """An experiment folder that cannot be read back (farm claims, farm report): names the
    file or the point and the problem."""


class CliError(SwarmFarmError):
    """A bad command line."""


class ActionError(InputError):
    """An action the allocation env refuses: not of the action space's shape, not numbers,
    or not finite (a workers.InputError, so a ValueError)."""


class TrainingDiverged(SwarmFarmError):
    """A training run whose losses, parameters or actions became non-finite: names the step."""


class ModelError(SwarmFarmError):
    """A run folder's model.zip that stable-baselines3 cannot load, or whose parameters are not finite."""


class StorageError(SwarmFarmError):
    """An experiment's storage that failed, or lost objects, while the experiment ran: names the
    storage (its URI), the object and what is wrong."""
