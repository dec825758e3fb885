"""How a run stops early (bad input before any work, a blow-up during it, a run folder
another run holds) and how a dataset can be found unfit to read."""


class ConfigError(ValueError):
    """Bad input, found before any work starts.

    ``key`` is the dotted config key at fault; the message says what is allowed.
    ``str(err)`` is the single line a user sees.
    """

    def __init__(self, key: str, message: str):
        self.key = key
        self.message = message
        super().__init__(f"{key}: {message}")


class SimulationDiverged(RuntimeError):
    """A run blew up (NaN, CFL far exceeded, energy runaway) at ``step`` for ``reason``."""

    def __init__(self, step: int, reason: str):
        self.step = step
        self.reason = reason
        super().__init__(f"diverged at step {step}: {reason}")


class FolderBusy(RuntimeError):
    """Another live run holds the lock of this run folder (windbench.sweep.FolderLock)."""


class DatasetUnreadable(OSError):
    """A dataset that cannot be trusted: it does not open, or a checksum does not match.

    ``str(err)`` is the reason, e.g. ``checksum: variable 'wind' is damaged (...)``.
    """
