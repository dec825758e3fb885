"""Structured configs: the schema Hydra checks every run against (types and known keys).

The ConfigStore holds ``windbench_schema`` (the root) and ``scene_schema``; each wind
backend declares and registers its own schema beside its code
(:func:`windbench.wind.registry.register_backend`), so a wrong type or an unknown key
fails at composition, before any work.

A key declared with :func:`setting` also carries its unit, its meaning and its allowed
values (``gt``/``ge``/``le`` bounds or ``choices``): :func:`check_values` checks them before
any work and ``windbench --help`` lists them, so each fact lives here once.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hydra.core.config_store import ConfigStore
from omegaconf import MISSING, DictConfig, ListConfig, OmegaConf

from windbench.errors import ConfigError


def config_dir() -> Path:
    """``conf/`` of a source checkout (where a user edits), else the configs shipped in the
    installed package (``windbench/conf``, mapped from ``conf/`` when the wheel is built)."""
    package = Path(__file__).resolve().parent
    checkout = package.parent
    if (checkout / "pyproject.toml").is_file() and (checkout / "conf" / "config.yaml").is_file():
        return checkout / "conf"
    return package / "conf"


def setting(
    default: Any,
    units: str = "",
    doc: str = "",
    *,
    gt: float | None = None,
    ge: float | None = None,
    le: float | None = None,
    choices: tuple[str, ...] | None = None,
    when: tuple[str, str] | None = None,
) -> Any:
    """A schema field with its unit (UDUNITS, ``1`` for a count or ratio, ``""`` for none),
    a one-line meaning and the values allowed (checked by :func:`check_values`); ``when``
    = (sibling key, value): the field is read only when that key has that value (the
    report does not count it as swept among runs that do not read it)."""
    meta = {"units": units, "doc": doc, "gt": gt, "ge": ge, "le": le, "choices": choices}
    meta["when"] = when
    if isinstance(default, list | dict):
        return field(default_factory=lambda: type(default)(default), metadata=meta)
    return field(default=default, metadata=meta)


@dataclass
class DomainConfig:
    min: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    max: list[float] = field(default_factory=lambda: [1.0, 1.0, 1.0])


@dataclass
class BoundaryConfig:
    x_min: str = "inflow"
    x_max: str = "outflow"
    y_min: str = "slip"
    y_max: str = "slip"
    z_min: str = "no_slip"
    z_max: str = "slip"


@dataclass
class ProbeBoxConfig:
    min: list[float] = MISSING
    max: list[float] = MISSING


@dataclass
class LeeForceConfig:
    sheltered: str = MISSING
    exposed: str = MISSING


@dataclass
class SceneConfig:
    name: str = MISSING
    domain: DomainConfig = field(default_factory=DomainConfig)
    boundary: BoundaryConfig = field(default_factory=BoundaryConfig)
    wall_velocity: dict[str, list[float]] = field(default_factory=dict)
    sources: list[Any] = field(default_factory=list)
    bodies: list[Any] = field(default_factory=list)
    cloths: list[Any] = field(default_factory=list)
    probes: dict[str, ProbeBoxConfig] = field(default_factory=dict)
    lee_force: LeeForceConfig | None = None
    reference_speed: float | None = None
    wake: Any = None  # wake profiles behind an obstacle (windbench.scenes.WakeProbe)


@dataclass
class GridConfig:
    resolution: int = setting(32, "1", "cells along the longest domain axis (at least 4)")


@dataclass
class SimConfig:
    dt: float = setting(1.0 / 60.0, "s", "time step", gt=0)
    spinup: Any = setting(
        "auto", "s", "simulated before recording starts; auto: two flow-through times"
    )
    duration: Any = setting(
        1.0,
        "s",
        "simulated time recorded after the spin-up; auto: sim.window_flow_throughs "
        "flow-through times, at least 1 s",
    )
    window_flow_throughs: float = setting(
        1.0,
        "1",
        "flow-through times sim.duration=auto records (the steady window: its time means' "
        "sampling noise falls as 1/sqrt of it)",
        gt=0,
    )
    max_steps: int = setting(
        100_000, "1", "largest step count (sim.duration / sim.dt) accepted", ge=1
    )
    progress: bool = setting(
        True, "", "progress bar on a terminal, else a log line every tenth of the run"
    )
    fail_at_step: int | None = setting(
        None, "1", "fault injection: the run diverges at this step (tests)", ge=1
    )


# Flat plates: C_D 1.17 (square) to 1.98 (two-dimensional), normal-force coefficients below
# 2 at any incidence (Hoerner 1965); 3 leaves room for bluff shapes and rejects typos.
MAX_COEFFICIENT = 3.0


@dataclass
class AeroConfig:
    """Paper §3 coefficients; C_D = 1.17 is Hoerner's square plate normal to the flow."""

    drag_coefficient: float = setting(
        1.17, "1", "C_D of the paper's section 3 drag law", ge=0, le=MAX_COEFFICIENT
    )
    lift_coefficient: float = setting(
        0.6, "1", "C_L of the paper's section 3 lift law", ge=0, le=MAX_COEFFICIENT
    )
    air_density: float = setting(1.2, "kg m-3", "density of the air", gt=0)
    subgrid_law: bool = setting(
        True,
        "",
        "with wind.coupling=projection, add the section 3 law, on the air that passes "
        "through the cloth, to the pressure jump (false: the pressure jump alone)",
    )


@dataclass
class ClothMaterialConfig:
    """Default cloth material (SI); a cloth's own ``material`` dict overrides any key.

    Defaults: a light woven flag fabric (Kawabata-range figures): 0.15 kg/m^2, tensile
    stiffness 5000 N/m, shear 50 N/m, bending 1e-5 N m, Rayleigh damping time 1 ms.
    """

    density: float = setting(0.15, "kg m-2", "mass per area")
    stretch_stiffness: float = setting(5000.0, "N m-1", "membrane (tensile) stiffness Y")
    shear_stiffness: float = setting(50.0, "N m-1", "in-plane shear stiffness G")
    bend_stiffness: float = setting(1e-5, "N m", "bending stiffness B")
    damping: float = setting(1e-3, "s", "stiffness-proportional damping time")


@dataclass
class ClothConfig:
    """Cloth solver settings; see windbench.cloth.solver for the XPBD scheme."""

    solver: str = setting("xpbd", "", "cloth solver: xpbd | static (windbench.cloth.SOLVERS)")
    substeps: int = setting(8, "1", "XPBD substeps per sim.dt")
    edge_iterations: int = setting(
        2, "1", "passes over the threads (the first also the shear edges) per substep"
    )
    threads: bool = setting(
        True, "", "solve the stretch edges thread by thread (false: edge by edge)"
    )
    strain_limit: float = setting(
        0.03, "1", "warp/weft edges at most this much longer than at rest (0: off)"
    )
    limit_passes: int = setting(32, "1", "at most this many strain-limit passes per substep")
    gravity: float = setting(9.81, "m s-2", "gravity, along -z")
    collision_margin: float = setting(0.005, "m", "cloth keeps this distance from bodies")
    friction: float = setting(0.3, "1", "Coulomb coefficient cloth/body")
    self_collision: bool = setting(
        False,
        "",
        "cloth keeps its thickness from itself and from other cloths (off by default: it "
        "adds a contact search to the substeps, its cost in experiments/results/"
        "bench_cloth_self_collision.csv; without it a folding flag passes through itself, "
        "which the self_intersections figure counts)",
    )
    thickness: float = setting(
        0.005, "m", "self-contact distance between a vertex and another triangle", gt=0
    )
    energy_limit: float = setting(
        10.0, "1", "diverged: kinetic energy > limit x work done on the cloth"
    )
    material: ClothMaterialConfig = field(default_factory=ClothMaterialConfig)


@dataclass
class FramesConfig:
    """What the report's animations need (``output.frames``), kept every ``interval`` s.

    A frame holds a horizontal slice of the wind at height ``height``, the aerodynamic force
    on every cloth triangle and, with a backend that tracks arrival (particles), which cells
    of the slice the wind has reached; the cloth itself is kept every step
    (``cloth_position``).
    """

    interval: float = 0.0  # s of simulated time between frames (whole steps); 0: no frames
    height: float | None = None  # m, z of the wind slice; null: the lee box's centre


@dataclass
class OutputConfig:
    snapshots: int = setting(
        4, "1", "wind snapshots kept (evenly spaced, the last at the end)", ge=1
    )
    frames: FramesConfig = field(default_factory=FramesConfig)
    probe_points: int = setting(6, "1", "lee/free-stream probe lattice: points per axis", ge=1)
    window_blocks: int = setting(
        4,
        "1",
        "equal blocks of the steady window whose probe-wind means give the sampling error "
        "of its time mean (batch means)",
        ge=2,
    )
    filename: str = setting("windbench.nc", "", "dataset file name inside the run folder")


@dataclass
class ResumeConfig:
    """``resume=true`` is short for ``resume.enabled=true`` (windbench.cli)."""

    enabled: bool = setting(
        False, "", "skip a run whose complete dataset of the same config is there"
    )
    code: str = setting(
        "same",
        "",
        "same: rerun a complete run made by another git commit or windbench version; any: keep it",
        choices=("same", "any"),
    )


@dataclass
class RuntimeConfig:
    """How a run uses the machine (windbench.runtime); not part of its numbers."""

    threads: Any = setting(
        "auto",
        "1",
        "numba threads of the run; auto: the cores available / the launcher's parallel runs, "
        "kept to the cores other processes leave free where that is faster (re-read as it runs)",
    )
    compile_ahead: bool = setting(
        True,
        "",
        "on an empty numba cache, compile the cloth's kernels in a second process while the "
        "run compiles its wind's, when a core is spare (windbench.compile_ahead)",
    )


@dataclass
class WindbenchConfig:
    wind: Any = MISSING
    scene: SceneConfig = MISSING
    grid: GridConfig = field(default_factory=GridConfig)
    sim: SimConfig = field(default_factory=SimConfig)
    aero: AeroConfig = field(default_factory=AeroConfig)
    cloth: ClothConfig = field(default_factory=ClothConfig)
    output: OutputConfig = field(default_factory=OutputConfig)
    seed: int = setting(0, "1", "random seed (particle emission)", ge=0, le=2**32 - 1)
    resume: ResumeConfig = field(default_factory=ResumeConfig)
    runtime: RuntimeConfig = field(default_factory=RuntimeConfig)
    experiment: str | None = None


def register_configs() -> None:
    cs = ConfigStore.instance()
    cs.store(name="windbench_schema", node=WindbenchConfig)
    cs.store(group="scene", name="scene_schema", node=SceneConfig)


def allowed(meta: dict) -> str:
    """What a setting allows, in words: ``> 0 s``, ``in [0, 3]``, ``one of ['same', 'any']``
    (empty when any value of its type is fine)."""
    if meta.get("choices"):
        return f"one of {list(meta['choices'])}"
    units = f" {meta['units']}" if meta.get("units") not in ("", "1", None) else ""

    def num(x: float) -> str:
        return str(int(x)) if float(x).is_integer() and abs(x) < 1e15 else f"{x:g}"

    lo = f"> {num(meta['gt'])}" if meta.get("gt") is not None else None
    lo = lo or (f">= {num(meta['ge'])}" if meta.get("ge") is not None else None)
    if lo and meta.get("le") is not None:
        lo_b = meta["gt"] if meta.get("gt") is not None else meta["ge"]
        bracket = "(" if meta.get("gt") is not None else "["
        return f"in {bracket}{num(lo_b)}, {num(meta['le'])}]{units}"
    if lo:
        return lo + units
    return f"<= {num(meta['le'])}{units}" if meta.get("le") is not None else ""


def schema_fields(schema: type | None = None, prefix: str = ""):
    """(dotted key, dataclass field) of every :func:`setting` under ``schema`` (the root by
    default), depth first in declaration order."""
    schema = schema or WindbenchConfig
    for f in dataclasses.fields(schema):
        nested = f.default_factory if f.default_factory is not dataclasses.MISSING else None
        if isinstance(nested, type) and dataclasses.is_dataclass(nested):
            yield from schema_fields(nested, f"{prefix}{f.name}.")
        elif "units" in f.metadata:
            yield f"{prefix}{f.name}", f


def _in_range(value, meta: dict) -> bool:
    if meta.get("choices"):
        return value in meta["choices"]
    if not isinstance(value, int | float) or isinstance(value, bool):
        return True
    if meta.get("gt") is not None and not value > meta["gt"]:
        return False
    if meta.get("ge") is not None and not value >= meta["ge"]:
        return False
    return meta.get("le") is None or value <= meta["le"]


def check_finite(node, prefix: str = "") -> None:
    """ConfigError naming the first NaN or infinite number anywhere under ``node``."""
    if isinstance(node, DictConfig | ListConfig):
        node = OmegaConf.to_container(node, resolve=True)
    if isinstance(node, dict):
        for key, value in node.items():
            check_finite(value, f"{prefix}{key}.")
    elif isinstance(node, list):
        for i, value in enumerate(node):
            check_finite(value, f"{prefix[:-1]}[{i}].")
    elif isinstance(node, float) and not math.isfinite(node):
        raise ConfigError(prefix[:-1], f"must be a finite number, got {node}")


def check_values(cfg) -> None:
    """ConfigError for the first non-finite number or out-of-range :func:`setting` in ``cfg``
    (types are already checked by the schema when the config is composed)."""
    for key in cfg:
        if key != "hydra":  # Hydra's own node (when composed with it) is not a run setting
            check_finite(cfg[key], f"{key}.")
    check_settings(cfg, WindbenchConfig)


def check_settings(node, schema: type, prefix: str = "") -> None:
    """ConfigError for the first :func:`setting` of ``schema`` whose value in ``node`` is out
    of its range; the error names the key as ``prefix`` + its dotted path (a backend checks
    its ``wind`` node with prefix ``wind.``)."""
    for key, f in schema_fields(schema, prefix):
        value = OmegaConf.select(node, key.removeprefix(prefix), default=None)
        if value is not None and not _in_range(value, f.metadata):
            raise ConfigError(key, f"must be {allowed(f.metadata)}, got {value!r}")
