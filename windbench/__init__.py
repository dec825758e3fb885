"""windbench: the two wind models of Keckeisen et al. (WSCG 2004) behind one interface.

Paper: M. Keckeisen, S. Kimmerle, B. Thomaszewski, M. Wacker, "Modelling Effects of Wind
Fields in Cloth Animations", Journal of WSCG 12 (2004).
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("windbench")
except PackageNotFoundError:  # pragma: no cover - running from a source tree
    __version__ = "0.0.0+unknown"

__all__ = ["__version__"]
