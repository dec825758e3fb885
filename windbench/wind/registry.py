"""The wind-backend registry: a backend is one module (or package) plus one config file.

A backend module declares its config schema (a dataclass deriving from
:class:`WindConfig`) and registers its class::

    @dataclass
    class UniformNoiseConfig(WindConfig):
        name: str = "uniform_noise"
        amplitude: float = 1.0  # m/s

    @register_backend("uniform_noise", config=UniformNoiseConfig)
    class UniformNoiseWind(WindField): ...

and ``conf/wind/uniform_noise.yaml`` starts from the schema
(``defaults: [uniform_noise_schema, _self_]``). Registration stores the schema in Hydra's
ConfigStore as ``wind/<name>_schema``, so a wrong type or an unknown key fails when the
config is composed. :func:`discover` imports the built-in backends (every module or
package directly under :mod:`windbench.wind`) and the backends that installed packages
declare under the entry-point group ``windbench.wind_backends``; nothing central is
edited to add one.
"""

from __future__ import annotations

import importlib
import pkgutil
from dataclasses import dataclass
from importlib.metadata import entry_points

from hydra.core.config_store import ConfigStore
from omegaconf import MISSING

from windbench.errors import ConfigError

ENTRY_POINT_GROUP = "windbench.wind_backends"


@dataclass
class WindConfig:
    """Keys every backend has; a backend's schema derives from this one."""

    name: str = MISSING


@dataclass(frozen=True)
class Backend:
    """A registered backend: its config name, class and schema."""

    name: str
    cls: type
    config: type

    @property
    def schema_name(self) -> str:
        return f"{self.name}_schema"


_BACKENDS: dict[str, Backend] = {}


def register_backend(name: str, config: type):
    """Class decorator: register a WindField subclass under ``name`` with its schema."""
    if not (isinstance(config, type) and issubclass(config, WindConfig)):
        raise TypeError(f"backend {name!r}: config must be a WindConfig dataclass, got {config}")

    def decorate(cls):
        cls.name = name
        _BACKENDS[name] = Backend(name, cls, config)
        ConfigStore.instance().store(group="wind", name=f"{name}_schema", node=config)
        return cls

    return decorate


def discover() -> dict[str, Backend]:
    """Import the built-in backends and those of installed packages; the registry."""
    import windbench.wind as package

    for info in pkgutil.iter_modules(package.__path__):
        importlib.import_module(f"{package.__name__}.{info.name}")
    for entry in entry_points(group=ENTRY_POINT_GROUP):
        entry.load()
    return dict(_BACKENDS)


def backends() -> dict[str, Backend]:
    """The registered backends, discovering them on first use."""
    if not _BACKENDS:
        discover()
    return dict(_BACKENDS)


def get_backend(name: str) -> Backend:
    """The backend registered as ``name``; ConfigError listing the known ones otherwise."""
    known = backends()
    if name not in known:
        discover()  # a package may have been installed, or a module imported, since
        known = dict(_BACKENDS)
    if name not in known:
        raise ConfigError("wind", f"unknown backend {name!r}; allowed {sorted(known)}")
    return known[name]
