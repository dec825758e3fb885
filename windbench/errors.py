"""The two ways a run can stop early: bad input (before any work) or a blow-up (during it)."""


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
