"""windbench: the two wind models of Keckeisen et al. (WSCG 2004) behind one interface.

Paper: M. Keckeisen, S. Kimmerle, B. Thomaszewski, M. Wacker, "Modelling Effects of Wind
Fields in Cloth Animations", Journal of WSCG 12 (2004).

Importing the package prepares numba's environment before numba itself is loaded
(:func:`prepare_numba_environment`): OpenMP threads that sleep instead of spinning while
they wait, and a kernel cache that is writable wherever the package is installed.
"""

import os
import sys
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

try:
    __version__ = version("windbench")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    __version__ = "0.0.0+unknown"

__all__ = ["__version__", "numba_cache_dir", "prepare_numba_environment"]

# OpenMP workers that wait passively (sleep) rather than spin: a spinning worker holds a
# core that another process (or another run of a parallel sweep) needs, and a parallel
# kernel then waits for a descheduled thread. Read once, when the OpenMP runtime loads.
WAIT_POLICY = {"OMP_WAIT_POLICY": "passive"}


def numba_cache_dir(package: Path | None = None) -> Path | None:
    """Where numba should cache windbench's compiled kernels: None (numba's default,
    ``__pycache__`` beside the sources) when the package folder is writable, else
    ``$XDG_CACHE_HOME/windbench/numba`` (``~/.cache/...``), so that an install into a
    read-only site-packages compiles once per user rather than on every run."""
    package = package or Path(__file__).resolve().parent
    if os.access(package, os.W_OK):
        return None
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "windbench" / "numba"


def prepare_numba_environment() -> None:
    """Set what numba and its OpenMP runtime read when they load, unless the user has:
    the passive wait policy (:data:`WAIT_POLICY`, read when the first parallel kernel
    starts the OpenMP runtime) and, for a read-only install, the cache folder
    (:func:`numba_cache_dir`, read when numba is imported)."""
    for key, value in WAIT_POLICY.items():
        os.environ.setdefault(key, value)
    cache = numba_cache_dir()
    if cache is not None and "NUMBA_CACHE_DIR" not in os.environ and "numba" not in sys.modules:
        os.environ["NUMBA_CACHE_DIR"] = str(cache)


prepare_numba_environment()
