"""Structured configs: the schema Hydra checks every run against (types and known keys).

The ConfigStore holds ``windbench_schema`` (the root) and ``scene_schema``; each wind
backend declares and registers its own schema beside its code
(:func:`windbench.wind.registry.register_backend`), so a wrong type or an unknown key
fails at composition, before any work.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from hydra.core.config_store import ConfigStore
from omegaconf import MISSING


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


@dataclass
class GridConfig:
    resolution: int = 32  # cells along the longest domain axis


@dataclass
class SimConfig:
    dt: float = 1.0 / 60.0  # s
    duration: float = 1.0  # s of simulated time
    progress: bool = True  # tqdm bar (only on a terminal)
    fail_at_step: int | None = None  # fault injection: the run diverges at this step (tests)


@dataclass
class AeroConfig:
    """Paper §3 coefficients; C_D = 1.17 is Hoerner's square plate normal to the flow."""

    drag_coefficient: float = 1.17
    lift_coefficient: float = 0.6
    air_density: float = 1.2


@dataclass
class ClothMaterialConfig:
    """Default cloth material (SI); a cloth's own ``material`` dict overrides any key.

    Defaults: a light woven flag fabric (Kawabata-range figures): 0.15 kg/m^2, tensile
    stiffness 5000 N/m, shear 50 N/m, bending 1e-5 N m, Rayleigh damping time 1 ms.
    """

    density: float = 0.15  # kg/m^2, mass per area
    stretch_stiffness: float = 5000.0  # N/m, membrane (tensile) stiffness Y
    shear_stiffness: float = 50.0  # N/m, in-plane shear stiffness G
    bend_stiffness: float = 1e-5  # N m, bending stiffness B
    damping: float = 1e-3  # s, stiffness-proportional damping time


@dataclass
class ClothConfig:
    """Cloth solver settings; see windbench.cloth.solver for the XPBD scheme."""

    solver: str = "xpbd"  # see windbench.cloth.SOLVERS (xpbd | static)
    substeps: int = 8  # XPBD substeps per sim.dt
    edge_iterations: int = 2  # passes over the threads (the first also the shear edges) per substep
    threads: bool = True  # solve the stretch edges thread by thread (false: edge by edge)
    strain_limit: float = 0.03  # warp/weft edges at most this much longer than at rest (0: off)
    limit_passes: int = 32  # at most this many strain-limit passes over the threads per substep
    gravity: float = 9.81  # m/s^2, along -z
    collision_margin: float = 0.005  # m, cloth keeps this distance from bodies
    friction: float = 0.3  # Coulomb coefficient cloth/body
    energy_limit: float = 10.0  # diverged: kinetic energy > limit x work done on the cloth
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
    snapshots: int = 4  # wind snapshots kept (evenly spaced, last one at the end)
    frames: FramesConfig = field(default_factory=FramesConfig)
    probe_points: int = 6  # lee/free-stream probe lattice: points per axis
    filename: str = "windbench.nc"


@dataclass
class WindbenchConfig:
    wind: Any = MISSING
    scene: SceneConfig = MISSING
    grid: GridConfig = field(default_factory=GridConfig)
    sim: SimConfig = field(default_factory=SimConfig)
    aero: AeroConfig = field(default_factory=AeroConfig)
    cloth: ClothConfig = field(default_factory=ClothConfig)
    output: OutputConfig = field(default_factory=OutputConfig)
    seed: int = 0
    resume: bool = False
    experiment: str | None = None


def register_configs() -> None:
    cs = ConfigStore.instance()
    cs.store(name="windbench_schema", node=WindbenchConfig)
    cs.store(group="scene", name="scene_schema", node=SceneConfig)
