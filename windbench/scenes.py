"""Scenes (paper §5) built from config: domain, wind sources, bodies, cloths, probe boxes.

A :class:`Scene` is pure model: geometry and parameters, checked once, immutable. Every
wind backend reads the same scene, so the same ``sources`` drive the Navier-Stokes inflow,
the global superposition and the particle emitters.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from windbench.cloth.mesh import ClothMesh, mesh_from_config
from windbench.errors import ConfigError
from windbench.geometry.bodies import Body, body_from_config
from windbench.wind.primitives import Primitive, primitive_from_config
from windbench.wind.surface_layer import ground_roughness

FACES = ("x_min", "x_max", "y_min", "y_max", "z_min", "z_max")
BOUNDARY_KINDS = ("inflow", "outflow", "slip", "no_slip", "periodic", "rough")


@dataclass(frozen=True)
class Box:
    """An axis-aligned probe box."""

    lower: np.ndarray
    upper: np.ndarray

    def lattice(self, n: int) -> np.ndarray:
        """``n`` points per axis spread over the box (cell-centred), shape ``(n^3, 3)``."""
        axes = [
            self.lower[a] + (np.arange(n) + 0.5) * (self.upper[a] - self.lower[a]) / n
            for a in range(3)
        ]
        return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


@dataclass(frozen=True)
class WakeProbe:
    """Points behind an obstacle where the wake is measured: u/u0 along ``direction`` at
    ``distances`` x H behind ``origin`` (the obstacle's lee face at ground level) and
    ``heights`` x H above it, averaged over ``span_points`` points across the span; u0 is
    the undisturbed wind of the scene's sources at the same point."""

    origin: np.ndarray
    direction: np.ndarray  # unit vector along the wind
    height: float  # H, m
    distances: tuple[float, ...]  # in H
    heights: tuple[float, ...]  # in H
    span: np.ndarray  # (k, 3) offsets across the wind (m)

    def points(self) -> np.ndarray:
        """``(n_distances, n_heights, k, 3)`` world points."""
        up = np.array([0.0, 0.0, 1.0])
        d = np.asarray(self.distances)[:, None, None, None] * self.height * self.direction
        z = np.asarray(self.heights)[None, :, None, None] * self.height * up
        return self.origin + d + z + self.span[None, None, :, :]


def _wake(spec, domain: Box) -> WakeProbe:
    key = "scene.wake"
    allowed = {"origin", "direction", "height", "distances", "heights", "span", "span_points"}
    unknown = set(spec) - allowed
    if unknown:
        raise ConfigError(key, f"unknown key(s) {sorted(unknown)}; allowed {sorted(allowed)}")
    origin = np.asarray(list(spec["origin"]), dtype=float)
    direction = np.asarray(list(spec.get("direction", [1.0, 0.0, 0.0])), dtype=float)
    height = float(spec["height"])
    if origin.shape != (3,) or direction.shape != (3,) or not np.linalg.norm(direction) > 0:
        raise ConfigError(key, "origin and direction must be 3 numbers, direction non-zero")
    if not height > 0:
        raise ConfigError(f"{key}.height", f"must be > 0 m, got {height}")
    direction = direction / np.linalg.norm(direction)
    across = np.cross([0.0, 0.0, 1.0], direction)
    span = float(spec.get("span", 0.0))
    k = int(spec.get("span_points", 1))
    if k < 1 or span < 0:
        raise ConfigError(f"{key}.span_points", "must be >= 1 (and span >= 0 m)")
    offsets = (np.arange(k) + 0.5) / k - 0.5 if k > 1 else np.zeros(1)
    probe = WakeProbe(
        origin=origin,
        direction=direction,
        height=height,
        distances=tuple(float(d) for d in spec.get("distances", (2, 5, 10, 15))),
        heights=tuple(float(z) for z in spec.get("heights", (0.25, 0.5, 1.0))),
        span=offsets[:, None] * span * across,
    )
    pts = probe.points().reshape(-1, 3)
    if np.any(pts < domain.lower) or np.any(pts > domain.upper):
        raise ConfigError(key, "wake points leave the domain: shorten distances or span")
    return probe


@dataclass(frozen=True)
class Scene:
    """Model of one scene; see docs/design.md "Scene config" for the keys."""

    name: str
    lower: np.ndarray
    upper: np.ndarray
    boundary: Mapping[str, str]
    wall_velocity: Mapping[str, np.ndarray]
    sources: tuple[Primitive, ...]
    source_specs: tuple[Mapping, ...]  # raw entries: emission settings for the particles
    bodies: tuple[Body, ...]
    cloths: tuple[ClothMesh, ...]
    probes: Mapping[str, Box]
    lee_force: tuple[str, str] | None = None  # (sheltered cloth, exposed cloth)
    reference_speed: float = 1.0
    wake: WakeProbe | None = None
    extra: Mapping = field(default_factory=dict)

    def cloth_index(self, name: str) -> int:
        return [c.name for c in self.cloths].index(name)


def _as_dict(node) -> dict:
    try:
        from omegaconf import DictConfig, ListConfig, OmegaConf

        if isinstance(node, DictConfig | ListConfig):
            return OmegaConf.to_container(node, resolve=True)
    except ImportError:  # pragma: no cover
        pass
    return dict(node) if isinstance(node, Mapping) else node


def _box(spec, key) -> Box:
    lo = np.asarray(list(spec["min"]), dtype=float)
    hi = np.asarray(list(spec["max"]), dtype=float)
    if lo.shape != (3,) or hi.shape != (3,):
        raise ConfigError(key, "min and max must be 3 numbers each")
    if np.any(hi <= lo):
        raise ConfigError(f"{key}.max", f"must exceed {key}.min on every axis, got {lo} .. {hi}")
    return Box(lo, hi)


def _check_boundary(boundary: Mapping) -> dict:
    out = {}
    for face in FACES:
        kind = boundary.get(face)
        if kind not in BOUNDARY_KINDS:
            raise ConfigError(
                f"scene.boundary.{face}", f"must be one of {list(BOUNDARY_KINDS)}, got {kind!r}"
            )
        if kind == "rough" and face != "z_min":
            raise ConfigError(
                f"scene.boundary.{face}", "rough is the ground's kind: allowed on z_min only"
            )
        out[face] = kind
    for axis in "xyz":
        lo, hi = out[f"{axis}_min"], out[f"{axis}_max"]
        if (lo == "periodic") != (hi == "periodic"):
            raise ConfigError(
                f"scene.boundary.{axis}_min",
                f"periodic comes in pairs: {axis}_min={lo}, {axis}_max={hi}",
            )
    return out


def build_scene(cfg) -> Scene:
    """Check a ``scene`` config node and build the :class:`Scene` (raises ConfigError)."""
    cfg = _as_dict(cfg)
    name = cfg.get("name") or "scene"
    domain = _box(cfg["domain"], "scene.domain")
    boundary = _check_boundary(cfg.get("boundary", {}))
    wall_velocity = {}
    for face, vel in (cfg.get("wall_velocity") or {}).items():
        if face not in FACES or boundary[face] != "no_slip":
            raise ConfigError(f"scene.wall_velocity.{face}", "is allowed only on a no_slip face")
        wall_velocity[face] = np.asarray(vel, dtype=float)
    specs = tuple(cfg.get("sources") or ())
    sources = tuple(primitive_from_config(s, f"scene.sources[{i}]") for i, s in enumerate(specs))
    if boundary["z_min"] == "rough":
        ground_roughness(sources)
    bodies = tuple(
        body_from_config(b, f"scene.bodies[{i}]") for i, b in enumerate(cfg.get("bodies") or ())
    )
    cloths = tuple(
        mesh_from_config(c, f"scene.cloths[{i}]") for i, c in enumerate(cfg.get("cloths") or ())
    )
    names = [c.name for c in cloths]
    if len(set(names)) != len(names):
        raise ConfigError("scene.cloths", f"cloth names must be unique, got {names}")
    for i, cloth in enumerate(cloths):
        lo, hi = cloth.vertices.min(0), cloth.vertices.max(0)
        if np.any(lo < domain.lower) or np.any(hi > domain.upper):
            raise ConfigError(
                f"scene.cloths[{i}]",
                f"cloth {cloth.name!r} spans {lo} .. {hi}, outside the domain {domain.lower} .. {domain.upper}",
            )
    for i, body in enumerate(bodies):
        lo, hi = body.bounds()
        if body.kind != "plane" and (np.any(hi <= domain.lower) or np.any(lo >= domain.upper)):
            raise ConfigError(
                f"scene.bodies[{i}]", f"body lies entirely outside the domain ({lo} .. {hi})"
            )
    probes = {}
    for pname, pspec in (cfg.get("probes") or {}).items():
        box = _box(pspec, f"scene.probes.{pname}")
        if np.any(box.lower < domain.lower) or np.any(box.upper > domain.upper):
            raise ConfigError(
                f"scene.probes.{pname}",
                f"box {box.lower} .. {box.upper} leaves the domain {domain.lower} .. {domain.upper}",
            )
        probes[pname] = box
    lee_force = None
    if cfg.get("lee_force"):
        lf = cfg["lee_force"]
        for role in ("sheltered", "exposed"):
            if lf.get(role) not in names:
                raise ConfigError(f"scene.lee_force.{role}", f"must name one of the cloths {names}")
        lee_force = (lf["sheltered"], lf["exposed"])
    ref = cfg.get("reference_speed")
    if ref is None:
        ref = max((s.speed_scale() for s in sources), default=1.0) or 1.0
    if ref <= 0:
        raise ConfigError("scene.reference_speed", f"must be > 0, got {ref}")
    wake = _wake(cfg["wake"], domain) if cfg.get("wake") else None
    return Scene(
        name=name,
        lower=domain.lower,
        upper=domain.upper,
        boundary=boundary,
        wall_velocity=wall_velocity,
        sources=sources,
        source_specs=specs,
        bodies=bodies,
        cloths=cloths,
        probes=probes,
        lee_force=lee_force,
        reference_speed=float(ref),
        wake=wake,
    )
