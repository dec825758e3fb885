"""Where, how many and when each wind source emits its gust particles (paper §4.2.2).

"In our model every wind source is also a particle source ... The specific emission
intervals and amounts depend on the properties of the flow sources." An :class:`Emitter`
is the model of one source's emission, built by :func:`emitters_from_scene` from the
``wind`` config and the source's checked ``emit`` / ``gusts`` keys (:func:`emission_spec`).

Regions (the default per source kind; ``emit.box`` replaces it for any kind):
``uniform``: the domain faces the wind blows in through (``U . n_out < 0``), each weighted
by its flux ``|U . n| area``, so that the particle density is uniform in the volume;
``source``: a sphere of radius ``emit.radius`` (default ``max(core_radius, h / 2)``);
``sink``: all six domain faces, area-weighted; ``vortex``: a cylinder around its core
line, radius ``emit.radius`` (default: out to the farthest domain corner), uniform in
volume; ``emit.box`` ``{min: [x, y, z], max: [x, y, z]}``: uniform in the box (a box
flat along one axis is a rectangle, e.g. a nozzle).

Per-source keys (all optional)::

    emit:   {rate: 2000.0, radius: 0.5, box: {min: [...], max: [...]}}
    gusts:  {on: 1.0, off: 2.0, start: 0.0}

``emit.rate`` is candidates per second while the source emits (default
``wind.particles_per_second`` or, when that is null, the automatic rate
``wind.particles_per_cell * A / (h^2 * wind.memory)``: each cell of the emitting
cross-section A is crossed by about ``particles_per_cell`` new particles per memory
window). ``gusts``: emission during ``[start + k P, start + k P + on)``, ``P = on + off``.

Positions are stratified: the region is cut into strata about one cell wide and emission
proceeds in rounds in which every stratum emits one particle, at a jittered point, in a
seeded random order, so no emitting cell waits long for its next particle (plain random
emission leaves Poisson gaps). Everything random comes from
``numpy.random.default_rng([seed, source, block])``, a block being whole rounds of at
least ``BLOCK`` samples: the same seed gives the same particles bit for bit. Candidates
outside the grid or inside a rigid body are dropped by the backend.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from windbench.errors import ConfigError

FACES, BOX, SPHERE, CYLINDER = "faces", "box", "sphere", "cylinder"
EMIT_KEYS = {"rate", "radius", "box"}
GUST_KEYS = {"on", "off", "start"}
BLOCK = 4096  # samples drawn from one random stream (whole rounds, at least one)


@dataclass(frozen=True)
class GustSchedule:
    """On/off emission intervals: on during [start + k (on + off), ... + on), k >= 0."""

    on: float = np.inf
    off: float = 0.0
    start: float = 0.0

    def on_time(self, t: float) -> float:
        """Cumulative emitting time F(t) in [start, t] (s)."""
        if t <= self.start:
            return 0.0
        if not np.isfinite(self.on):
            return t - self.start
        period = self.on + self.off
        k, r = divmod(t - self.start, period)
        return k * self.on + min(r, self.on)

    def instant(self, c: np.ndarray) -> np.ndarray:
        """Inverse of F: the time at which the cumulative emitting time reaches ``c``."""
        if not np.isfinite(self.on):
            return self.start + c
        k, r = np.divmod(c, self.on)
        return self.start + k * (self.on + self.off) + r


@dataclass(frozen=True)
class Emitter:
    """Model of one source's emission: region, rate (1/s), gusts, strata and seed."""

    source: int
    region: str
    rate: float
    gusts: GustSchedule
    seed: int
    # region geometry: faces -> rows (axis, coord, lo_a, hi_a, lo_b, hi_b, weight);
    # box -> (min, max); sphere -> (centre, radius); cylinder -> (point, axis, s0, s1, R)
    geometry: tuple
    strata: np.ndarray  # (M, 3, 2): [lo, hi) of each stratum in the unit cube of points()

    def points(self, u: np.ndarray) -> np.ndarray:
        """Map unit-cube points ``u`` ``(n, >= 3)`` in [0, 1) to positions ``(n, 3)``."""
        n = u.shape[0]
        out = np.empty((n, 3))
        if self.region == BOX:
            lo, hi = self.geometry
            return lo + u[:, :3] * (hi - lo)
        if self.region == SPHERE:
            centre, radius = self.geometry
            cos_t = 1.0 - 2.0 * u[:, 0]
            sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t * cos_t))
            phi = 2.0 * np.pi * u[:, 1]
            out[:, 0] = sin_t * np.cos(phi)
            out[:, 1] = sin_t * np.sin(phi)
            out[:, 2] = cos_t
            return centre + radius * out
        if self.region == CYLINDER:
            point, axis, s0, s1, radius = self.geometry
            e1 = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
            e1 /= np.linalg.norm(e1)
            e2 = np.cross(axis, e1)
            s = s0 + (s1 - s0) * u[:, 0]
            r = radius * np.sqrt(u[:, 1])  # uniform in the disc's area
            phi = 2.0 * np.pi * u[:, 2]
            return (
                point
                + s[:, None] * axis
                + (r * np.cos(phi))[:, None] * e1
                + (r * np.sin(phi))[:, None] * e2
            )
        # FACES: u0 picks the face (by cumulative weight) and its first coordinate
        rows = self.geometry[0]
        if len(rows) == 1:
            row, f0 = rows[np.zeros(n, dtype=np.int64)], u[:, 0]
        else:
            cum = np.concatenate([[0.0], np.cumsum(rows[:, 6])])
            cum /= cum[-1]
            face = np.clip(np.searchsorted(cum, u[:, 0], side="right") - 1, 0, len(rows) - 1)
            f0 = (u[:, 0] - cum[face]) / (cum[face + 1] - cum[face])
            row = rows[face]
        axis = row[:, 0].astype(np.int64)
        at = np.arange(n)
        out[at, axis] = row[:, 1]
        out[at, (axis + 1) % 3] = row[:, 2] + f0 * (row[:, 3] - row[:, 2])
        out[at, (axis + 2) % 3] = row[:, 4] + u[:, 1] * (row[:, 5] - row[:, 4])
        return out

    @property
    def rounds_per_block(self) -> int:
        """Rounds drawn together from one random stream: about BLOCK samples a block."""
        return max(1, -(-BLOCK // len(self.strata)))

    def block_samples(self, b: int) -> np.ndarray:
        """Block b: rounds b B .. b B + B - 1, each the M strata (one point each) in a seeded
        random order; ``(B M, 4)`` unit-cube points (columns 0-2) and instants (column 3)."""
        m, rounds = len(self.strata), self.rounds_per_block
        rng = np.random.default_rng([self.seed, self.source, b])
        order = rng.permuted(np.tile(np.arange(m), (rounds, 1)), axis=1).reshape(-1)
        jitter = rng.random((len(order), 4))
        box = self.strata[order]
        out = np.empty((len(order), 4))
        out[:, :3] = box[:, :, 0] + jitter[:, :3] * (box[:, :, 1] - box[:, :, 0])
        out[:, 3] = jitter[:, 3]
        return out

    def emit(self, t0: float, t1: float, carry: float, counter: int, cache: dict | None = None):
        """Candidates emitted in [t0, t1): (positions, emission instants, carry, counter).

        The number is ``rate * (on-time in the step) + carry`` rounded down; the fraction is
        carried to the next step, so the long-run count is exact. Particle n is sample
        n mod (B M) of block n // (B M) (:meth:`block_samples`). ``cache`` (the caller's
        state, optional) keeps the last block drawn, so a block is drawn once, not once
        per step that uses it: the cost per step is O(particles emitted).
        """
        f0, f1 = self.gusts.on_time(t0), self.gusts.on_time(t1)
        expected = self.rate * (f1 - f0) + carry
        n = int(np.floor(expected))
        carry = expected - n
        per = len(self.strata) * self.rounds_per_block
        cache = {} if cache is None else cache
        chunks = [np.zeros((0, 4))]
        last = (counter + n - 1) // per if n else counter // per - 1
        for b in range(counter // per, last + 1):
            if cache.get("block") != b:
                cache["block"], cache["samples"] = b, self.block_samples(b)
            lo = max(counter - b * per, 0)
            chunks.append(cache["samples"][lo : min(counter + n - b * per, per)])
        u = np.concatenate(chunks) if len(chunks) > 2 else chunks[-1]
        instants = self.gusts.instant(f0 + u[:, 3] * (f1 - f0))
        return self.points(u), np.clip(instants, t0, t1), carry, counter + n


def _grid_strata(counts, lows=(0.0, 0.0, 0.0), highs=(1.0, 1.0, 1.0)) -> np.ndarray:
    """Strata (M, 3, 2) of the box [lows, highs) cut into counts[d] equal parts along d."""
    edges = [np.linspace(lows[d], highs[d], int(counts[d]) + 1) for d in range(3)]
    idx = np.indices([int(c) for c in counts]).reshape(3, -1).T
    out = np.empty((len(idx), 3, 2))
    for d in range(3):
        out[:, d, 0] = edges[d][idx[:, d]]
        out[:, d, 1] = edges[d][idx[:, d] + 1]
    return out


def _cells(length: float, h: float) -> int:
    return max(1, int(round(length / h)))


def _faces(lower, upper, weights, h) -> tuple[np.ndarray, np.ndarray]:
    """Face rows (axis, coord, lo_a, hi_a, lo_b, hi_b, weight) and their strata.

    A face whose flux per area is a fraction c of the strongest face's is cut into
    strata of about h^2 / c (exactly its cells for the face of an axis-aligned wind);
    each face's share of the unit interval u0 is its stratum count, so every stratum
    carries about the same flux and one particle per stratum per round is flux-weighted.
    A face on the upper side sits one part in 10^9 of the domain inside, so that its
    particles start in the last cell rather than just outside the grid.
    """
    rows, grids = [], []
    h_in = 1e-9 * float((upper - lower).max())
    ext = upper - lower
    areas = np.array([ext[(a + 1) % 3] * ext[(a + 2) % 3] for a in range(3)])
    top = (weights / areas[:, None]).max()  # the strongest flux per area
    for axis in range(3):
        a, b = (axis + 1) % 3, (axis + 2) % 3
        area = (upper[a] - lower[a]) * (upper[b] - lower[b])
        for side, coord in ((0, lower[axis]), (1, upper[axis] - h_in)):
            w = weights[axis, side]
            if w > 0:
                shrink = np.sqrt(w / area / top)  # flux per area relative to the strongest
                m = (
                    _cells(shrink * (upper[a] - lower[a]), h),
                    _cells(shrink * (upper[b] - lower[b]), h),
                )
                rows.append([axis, coord, lower[a], upper[a], lower[b], upper[b], m[0] * m[1]])
                grids.append(m)
    rows = np.asarray(rows, dtype=np.float64)
    cum = np.concatenate([[0.0], np.cumsum(rows[:, 6])]) / rows[:, 6].sum()
    strata = [
        _grid_strata((m[0], m[1], 1), (cum[f], 0.0, 0.0), (cum[f + 1], 1.0, 1.0))
        for f, m in enumerate(grids)
    ]
    return rows, np.concatenate(strata)


def _vec3(value, key: str) -> np.ndarray:
    arr = np.asarray(list(value), dtype=float)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ConfigError(key, f"must be 3 finite numbers, got {list(value)}")
    return arr


def _positive(spec: Mapping, name: str, key: str, allow_zero=False, allow_inf=False):
    value = float(spec[name])
    ok = (value >= 0 if allow_zero else value > 0) and (allow_inf or np.isfinite(value))
    if not ok:
        raise ConfigError(
            f"{key}.{name}", f"must be {'>= 0' if allow_zero else '> 0'}, got {value}"
        )
    return value


def gust_schedule(spec, key: str) -> GustSchedule:
    """Check a source's ``gusts`` entry (None: always on)."""
    if spec is None:
        return GustSchedule()
    if not isinstance(spec, Mapping):
        raise ConfigError(key, f"must be a mapping with keys {sorted(GUST_KEYS)}")
    unknown = set(spec) - GUST_KEYS
    if unknown:
        raise ConfigError(key, f"unknown key(s) {sorted(unknown)}; allowed {sorted(GUST_KEYS)}")
    if "on" not in spec or "off" not in spec:
        raise ConfigError(key, "needs both 'on' and 'off' (seconds)")
    return GustSchedule(
        on=_positive(spec, "on", key),
        off=_positive(spec, "off", key, allow_zero=True),
        start=float(spec.get("start", GustSchedule.start)),
    )


def _cross_section(kind: str, velocity, lower, upper) -> tuple[np.ndarray, float]:
    """Face weights (3, 2) of a faces region and its automatic-rate cross-section (m^2)."""
    ext = upper - lower
    areas = np.array([ext[1] * ext[2], ext[0] * ext[2], ext[0] * ext[1]])
    weights = np.zeros((3, 2))
    if kind == "uniform":
        speed = np.linalg.norm(velocity)
        for axis in range(3):
            flux = velocity[axis] * areas[axis]  # blows in through min if > 0, max if < 0
            weights[axis, 0 if flux > 0 else 1] = abs(flux)
        return weights, float(weights.sum() / speed) if speed > 0 else 0.0
    weights[:, :] = areas[:, None]  # sink: the whole boundary
    return weights, float(weights.sum())


@dataclass(frozen=True)
class EmissionSpec:
    """One source's checked ``emit`` and ``gusts`` entries (None: not set)."""

    rate: float | None
    radius: float | None
    box: tuple[np.ndarray, np.ndarray] | None
    gusts: GustSchedule


def _box(box, key: str) -> tuple[np.ndarray, np.ndarray]:
    if not isinstance(box, Mapping) or set(box) != {"min", "max"}:
        raise ConfigError(key, "must be {min: [x, y, z], max: [x, y, z]}")
    lo, hi = _vec3(box["min"], f"{key}.min"), _vec3(box["max"], f"{key}.max")
    if np.any(hi < lo):
        raise ConfigError(f"{key}.max", f"must be >= min on every axis, got {lo} .. {hi}")
    return lo, hi


def emission_spec(prim, spec: Mapping, key: str) -> EmissionSpec:
    """Check one scene source's ``emit`` / ``gusts`` keys; ConfigError naming the first bad one."""
    emit = spec.get("emit") or {}
    if not isinstance(emit, Mapping):
        raise ConfigError(f"{key}.emit", f"must be a mapping with keys {sorted(EMIT_KEYS)}")
    unknown = set(emit) - EMIT_KEYS
    if unknown:
        raise ConfigError(
            f"{key}.emit", f"unknown key(s) {sorted(unknown)}; allowed {sorted(EMIT_KEYS)}"
        )
    if "radius" in emit and prim.kind == "uniform":
        raise ConfigError(f"{key}.emit.radius", "applies to source, sink and vortex only")
    gusts = gust_schedule(spec.get("gusts"), f"{key}.gusts")
    box = _box(emit["box"], f"{key}.emit.box") if emit.get("box") is not None else None
    if box is None and prim.kind == "uniform" and not np.any(np.asarray(prim.velocity)):
        raise ConfigError(f"{key}.velocity", "a uniform source needs a non-zero velocity")
    radius = _positive(emit, "radius", f"{key}.emit") if "radius" in emit else None
    rate = _positive(emit, "rate", f"{key}.emit", allow_zero=True) if "rate" in emit else None
    return EmissionSpec(rate, radius, box, gusts)


def emission_specs(scene) -> tuple[EmissionSpec, ...]:
    """The checked emission settings of every scene source (what ``check`` needs)."""
    return tuple(
        emission_spec(prim, spec, f"scene.sources[{i}]")
        for i, (prim, spec) in enumerate(zip(scene.sources, scene.source_specs, strict=True))
    )


def _region(prim, spec: EmissionSpec, lower, upper, h):
    """(region, geometry, strata, cross-section of the automatic rate) of one source."""
    ext = upper - lower
    largest_face = float(np.sort(ext)[1:].prod())
    if spec.box is not None:
        lo, hi = spec.box
        flat = np.sort(np.where(hi - lo > 0, hi - lo, 0.0))[1:]
        section = float(flat.prod()) if flat.prod() > 0 else h * h
        return BOX, (lo, hi), _grid_strata([_cells(v, h) for v in hi - lo]), section
    if prim.kind in ("uniform", "sink"):
        weights, section = _cross_section(prim.kind, np.asarray(prim.velocity), lower, upper)
        rows, strata = _faces(lower, upper, weights, h)
        return FACES, (rows,), strata, section
    centre = np.asarray(prim.center, dtype=float)
    if prim.kind == "source":
        r = spec.radius or max(prim.core_radius, 0.5 * h)
        m = _cells(np.sqrt(2 * np.pi) * r, h)  # (cos theta, phi) strata ~ h^2 each
        return SPHERE, (centre, r), _grid_strata((m, 2 * m, 1)), largest_face
    # vortex: a cylinder around the core line, out to the farthest domain corner
    axis = np.asarray(prim.axis, dtype=float)
    axis = axis / np.linalg.norm(axis)
    corners = lower + ext * np.array(
        [[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], dtype=float
    )
    s = (corners - centre) @ axis
    r = spec.radius or float(np.linalg.norm((corners - centre) - s[:, None] * axis, axis=1).max())
    strata = _grid_strata((_cells(float(s.max() - s.min()), h), _cells(r, h), 1))
    return CYLINDER, (centre, axis, float(s.min()), float(s.max()), r), strata, largest_face


def emitters_from_scene(scene, grid, wind_cfg, seed: int) -> tuple[Emitter, ...]:
    """One :class:`Emitter` per scene source (see module docstring for the keys)."""
    lower, upper = np.asarray(grid.lower, dtype=float), np.asarray(grid.upper, dtype=float)
    emitters = []
    for i, (prim, spec) in enumerate(zip(scene.sources, emission_specs(scene), strict=True)):
        region, geometry, strata, section = _region(prim, spec, lower, upper, grid.h)
        if spec.rate is not None:
            rate = spec.rate
        elif wind_cfg.particles_per_second is not None:
            rate = float(wind_cfg.particles_per_second)
        else:  # automatic: particles_per_cell per emitting cell per memory window
            rate = wind_cfg.particles_per_cell * section / (grid.h * grid.h * wind_cfg.memory)
        emitters.append(Emitter(i, region, rate, spec.gusts, int(seed), geometry, strata))
    return tuple(emitters)
