"""windbench: the two wind models of Keckeisen et al. (WSCG 2004) behind one interface.

Paper: M. Keckeisen, S. Kimmerle, B. Thomaszewski, M. Wacker, "Modelling Effects of Wind
Fields in Cloth Animations", Journal of WSCG 12 (2004).

Importing the package prepares numba's environment before numba itself is loaded
(:func:`prepare_numba_environment`): OpenMP threads that sleep instead of spinning while
they wait, and a kernel cache that is writable wherever the package is installed and
belongs to this version of the sources.
"""

import hashlib
import os
import shutil
import sys
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

try:
    __version__ = version("windbench")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    __version__ = "0.0.0+unknown"

__all__ = [
    "__version__",
    "numba_cache_dir",
    "prepare_numba_environment",
    "set_environment",
    "source_fingerprint",
]

# OpenMP workers that wait passively (sleep) rather than spin: a spinning worker holds a
# core that another process (or another run of a parallel sweep) needs, and a parallel
# kernel then waits for a descheduled thread. Read once, when the OpenMP runtime loads.
WAIT_POLICY = {"OMP_WAIT_POLICY": "passive"}


CACHE_KEEP = 4  # source versions whose compiled kernels a cache folder keeps
_SET: dict[str, str] = {}  # the variables :func:`prepare_numba_environment` set


def source_fingerprint(package: Path) -> str:
    """16 hex digits of a SHA-256 over the package's Python sources, paths and contents."""
    sources = []
    for folder, subfolders, files in os.walk(package):
        subfolders[:] = [d for d in subfolders if not d.startswith((".", "__"))]  # caches
        sources += [Path(folder) / f for f in files if f.endswith(".py")]
    digest = hashlib.sha256()
    for path in sorted(sources):
        digest.update(path.relative_to(package).as_posix().encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def numba_cache_dir(package: Path | None = None) -> Path:
    """Where numba caches windbench's compiled kernels: ``<base>/<source fingerprint>``,
    base ``.numba_cache`` in the package folder when that is writable, else
    ``$XDG_CACHE_HOME/windbench/numba`` (``~/.cache/...``: an install into a read-only
    site-packages compiles once per user, not on every run). One folder per version of the
    sources because numba checks a cached kernel against its own source file only: a
    kernel compiled together with a function of another module kept that function's old
    code after it changed (an updated checkout ran its cloth solver with the self-contacts
    of an earlier version, and gave other numbers than a fresh clone)."""
    package = package or Path(__file__).resolve().parent
    if os.access(package, os.W_OK):
        base = package / ".numba_cache"
    else:
        base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "windbench"
        base = base / "numba"
    return base / source_fingerprint(package)


def prune_cache(folder: Path, keep: int = CACHE_KEEP) -> None:
    """Mark ``folder`` as just used and remove its sibling version folders beyond the
    ``keep`` - 1 most recently used others."""
    folder.mkdir(parents=True, exist_ok=True)
    os.utime(folder)
    others = [p for p in folder.parent.iterdir() if p.is_dir() and p != folder]
    others.sort(key=lambda p: p.stat().st_mtime, reverse=True)
    for old in others[keep - 1 :]:
        shutil.rmtree(old, ignore_errors=True)


def prepare_numba_environment() -> None:
    """Set what numba and its OpenMP runtime read when they load, unless the user has:
    the passive wait policy (:data:`WAIT_POLICY`, read when the first parallel kernel
    starts the OpenMP runtime) and the cache folder of these sources
    (:func:`numba_cache_dir`, read when numba is imported)."""
    for key, value in WAIT_POLICY.items():
        if key not in os.environ:
            os.environ[key] = _SET[key] = value
    if "NUMBA_CACHE_DIR" not in os.environ and "numba" not in sys.modules:
        cache = numba_cache_dir()
        try:
            prune_cache(cache)
        except OSError:  # a folder that cannot be made: numba reports it when it caches
            pass
        os.environ["NUMBA_CACHE_DIR"] = _SET["NUMBA_CACHE_DIR"] = str(cache)


def set_environment() -> dict[str, str]:
    """The environment variables the package set on import (not those the user had set):
    a benchmark runs another program without them to time it as it ships."""
    return dict(_SET)


prepare_numba_environment()
