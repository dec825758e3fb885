"""Animations of the paper scenes: the backends side by side, frame by frame (``output.frames``).

One animation per scene, drawn from the run datasets (no physics is re-run): a column per
backend (the finest run of each that recorded frames), the cloth on top with every triangle
coloured by its aerodynamic pressure ``|F| / A`` (Pa) and below it the wind speed in the
horizontal slice the runs recorded (through the lee box), each row on one colour scale
shared by all backends and frames. In the particle-tracing column the slice cells that no
gust particle has reached yet are greyed out: that is wind not yet arrived, not lee (see
:mod:`windbench.report.frames`).

Encoded as H.264 MP4 through ``imageio-ffmpeg`` (its own ffmpeg binary), or as an animated
GIF through Pillow when that encoder is not installed; a tqdm bar runs while encoding.
Frames are played at :data:`PLAYBACK_FPS`, i.e. slowed down by ``PLAYBACK_FPS x interval``.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import matplotlib
import numpy as np
import xarray as xr
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from tqdm.auto import tqdm

from windbench.report import figures as F
from windbench.report.collect import RunRecord
from windbench.report.frames import RunFrames, wind_direction

PLAYBACK_FPS = 10.0  # frames shown per second of video
DPI = 80
BLOCK = 16  # H.264 macro block: frame sides are padded to a multiple of it
GIF_REDUCE = 2  # GIF fallback: frames shrunk by this factor per side
CRF = 28  # x264 constant rate factor (0 best .. 51 worst): small files, clean flat colours
WINDS = ("navier_stokes", "particles", "global")  # column order, as in Figs. 4/5
FRAMES_COMMAND = "output.frames.interval=0.02"  # what a run needs to be animated


@dataclass
class Animated:
    name: str  # file stem under figures/
    title: str
    caption: str
    file: str  # file name under figures/ (.mp4 or .gif)


@dataclass
class Column:
    wind: str
    record: RunRecord
    frames: RunFrames


def columns(records: Sequence[RunRecord], scene: str) -> list[Column]:
    """The finest run of each backend on ``scene`` that recorded frames, in :data:`WINDS` order."""
    found = [(wind, F.pick_with_frames(records, scene, wind)) for wind in WINDS]
    return [Column(wind, *pair) for wind, pair in found if pair is not None]


# ---------------------------------------------------------------------------- drawing


class SceneAnimation:
    """One scene's figure, drawn once and updated frame by frame (a fixed layout)."""

    def __init__(self, cols: list[Column]):
        self.cols = cols
        self.with_cloth = cols[0].frames.triangles.size > 0
        with xr.open_dataset(cols[0].record.path) as ds:
            self.scene = F.scene_of(ds)
        self.direction = wind_direction(self.scene)
        self.times = min((c.frames.times for c in cols), key=len)
        n = len(cols)
        height = 6.0 if self.with_cloth else 3.4
        fig = Figure(figsize=(3.6 * n + 1.2, height), dpi=DPI, layout="constrained")
        self.fig = fig
        self.rows = 2 if self.with_cloth else 1
        ratios = [1.2, 1.0] if self.with_cloth else [1.0]
        self.grid = fig.add_gridspec(self.rows, n, height_ratios=ratios)
        self.p_norm = Normalize(0.0, F._shared_max([c.frames.pressure for c in cols]))
        self.u_norm = Normalize(0.0, F._shared_max([c.frames.speed for c in cols], 99.5))
        self.polys, self.images, self.overlays, self.dots = [], [], [], []
        self.view = F._view_box(self.scene, [c.frames.positions for c in cols], margin=0.15)
        cloth_axes = [self._cloth_panel(j, c) for j, c in enumerate(cols) if self.with_cloth]
        slice_axes = [self._slice_panel(j, c) for j, c in enumerate(cols)]
        self._colorbars_and_key(cloth_axes, slice_axes)
        self.title = fig.suptitle(" ")
        self.canvas = FigureCanvasAgg(fig)
        self.update(0)
        self.canvas.draw()
        fig.set_layout_engine("none")  # frozen: the panels do not move between frames

    def _cloth_panel(self, j: int, col: Column):
        """Top row: the cloth in 3D coloured by |F|/A, with the scene's bodies."""
        fr = col.frames
        lo, hi = self.view
        ax = self.fig.add_subplot(self.grid[0, j], projection="3d")
        F._draw_bodies_3d(ax, self.scene, lo, hi)
        self.polys.append(
            F._pressure_cloth_3d(ax, fr.positions[0], fr.triangles, fr.pressure[0], self.p_norm)
        )
        F._frame_3d(ax, lo, hi, zoom=1.15)
        ax.set_title(f"{col.wind} (resolution {col.record.settings['resolution']})")
        return ax

    def _slice_panel(self, j: int, col: Column):
        """Bottom row: |u| in the horizontal slice, grey where particles have not arrived."""
        fr = col.frames
        ax = self.fig.add_subplot(self.grid[self.rows - 1, j])
        style = dict(origin="lower", extent=fr.extent, interpolation="nearest")
        speed = ax.imshow(fr.speed[0].T, norm=self.u_norm, cmap=F.SPEED_CMAP, **style)
        self.images.append(speed)
        self.overlays.append(ax.imshow(F._not_arrived(fr, 0, self.direction), **style))
        F._draw_bodies_xy(ax, self.scene, fr.slice_z)
        (dots,) = ax.plot([], [], ".", color="tab:red", ms=1.0)
        self.dots.append(dots)
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        if not self.with_cloth:
            ax.set_title(col.wind)
        return ax

    def _colorbars_and_key(self, cloth_axes: list, slice_axes: list) -> None:
        fig = self.fig
        if cloth_axes:
            fig.colorbar(
                F._mappable(self.p_norm, F.PRESSURE_CMAP),
                ax=cloth_axes,
                label="|F| / A (Pa)",
                shrink=0.8,
                pad=0.08,  # clear of the 3D axes' z labels
                extend="max",
            )
        fig.colorbar(
            F._mappable(self.u_norm, F.SPEED_CMAP),
            ax=slice_axes,
            label=f"|u| at z = {self.cols[0].frames.slice_z:.3g} m (m/s)",
            shrink=0.8,
            extend="max",
        )
        particles = any(c.frames.reached is not None for c in self.cols)
        fig.legend(
            handles=_key(particles, self.with_cloth),
            loc="outside lower center",
            ncol=3,
            fontsize=8,
            frameon=False,
        )

    def update(self, k: int) -> None:
        t = float(self.times[k])
        self.title.set_text(f"{self.scene.name}: t = {t:.2f} s")
        for j, col in enumerate(self.cols):
            fr = col.frames
            i = fr.nearest(t)
            if self.polys:
                poly = self.polys[j]
                poly.set_verts(fr.positions[i][fr.triangles])
                colours = matplotlib.colormaps[F.PRESSURE_CMAP](self.p_norm(fr.pressure[i]))
                poly.set_facecolor(colours)
                self.dots[j].set_data(fr.positions[i][:, 0], fr.positions[i][:, 1])
            self.images[j].set_data(fr.speed[i].T)
            self.overlays[j].set_data(F._not_arrived(fr, i, self.direction))

    def rgb(self, k: int) -> np.ndarray:
        """Frame k as an (h, w, 3) uint8 image, sides padded to a multiple of :data:`BLOCK`."""
        self.update(k)
        self.canvas.draw()
        img = np.asarray(self.canvas.buffer_rgba())[..., :3]
        h, w = img.shape[:2]
        pad = ((0, -h % BLOCK), (0, -w % BLOCK), (0, 0))
        return np.pad(img, pad, constant_values=255)

    def frames(self) -> Iterator[np.ndarray]:
        for k in range(len(self.times)):
            yield self.rgb(k)


def _key(particles: bool, with_cloth: bool) -> list:
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles = [Patch(fc="0.4", ec="k", label="bodies cut by the slice")]
    if with_cloth:
        handles.append(
            Line2D([], [], ls="", marker=".", color="tab:red", label="cloth vertices (projected)")
        )
    if particles:
        handles.append(Patch(fc=F.NOT_ARRIVED_RGBA, ec="0.5", label=F.NOT_ARRIVED_LABEL))
    return handles


# ---------------------------------------------------------------------------- encoding


def encoder_available() -> bool:
    try:
        import imageio_ffmpeg  # noqa: F401
    except ImportError:
        return False
    return True


def encode(frames: Iterator[np.ndarray], n: int, stem: Path, fps: float, fmt: str, progress: bool):
    """Write the frames to ``stem.mp4`` (H.264) or ``stem.gif``; return the path written."""
    bar = tqdm(
        frames,
        total=n,
        desc=f"encoding {stem.name}.{fmt}",
        unit="frame",
        disable=not (progress and sys.stderr.isatty()),
    )
    if fmt == "mp4":
        return _mp4(bar, stem.with_suffix(".mp4"), fps)
    if fmt == "gif":
        return _gif(bar, stem.with_suffix(".gif"), fps)
    raise ValueError(f"animation format must be mp4 or gif, got {fmt!r}")


def _mp4(frames, path: Path, fps: float) -> Path:
    import imageio_ffmpeg

    writer = None
    try:
        for img in frames:
            if writer is None:
                writer = imageio_ffmpeg.write_frames(
                    str(path),
                    (img.shape[1], img.shape[0]),
                    fps=fps,
                    codec="libx264",
                    pix_fmt_out="yuv420p",
                    quality=None,
                    macro_block_size=BLOCK,
                    ffmpeg_log_level="error",
                    output_params=["-crf", str(CRF), "-movflags", "+faststart"],
                )
                writer.send(None)
            writer.send(np.ascontiguousarray(img))
    finally:
        if writer is not None:
            writer.close()
    return path


def _gif(frames, path: Path, fps: float) -> Path:
    from PIL import Image

    images = [  # half size: a GIF stores every frame whole
        Image.fromarray(img).reduce(GIF_REDUCE).convert("P", palette=Image.Palette.ADAPTIVE)
        for img in frames
    ]
    images[0].save(
        path,
        save_all=True,
        append_images=images[1:],
        duration=int(round(1000 / fps)),
        loop=0,
        optimize=True,
    )
    return path


# ---------------------------------------------------------------------------- report entry


def title(scene: str) -> str:
    return f"Animation: {scene}"


def animate(
    records: Sequence[RunRecord], scene: str, folder: Path, progress: bool = True, fmt=None
) -> Animated | F.Missing:
    """The animation of ``scene`` from the runs' frames, or what runs it needs."""
    name = f"anim_{scene}"
    cols = columns(records, scene)
    if not cols:
        return F.Missing(
            name,
            title(scene),
            f"runs of `{scene}` that record frames: `windbench -m scene={scene} "
            f"wind={','.join(WINDS)} {FRAMES_COMMAND}`",
        )
    fmt = fmt or ("mp4" if encoder_available() else "gif")
    anim = SceneAnimation(cols)
    folder.mkdir(parents=True, exist_ok=True)
    path = encode(anim.frames(), len(anim.times), folder / name, PLAYBACK_FPS, fmt, progress)
    return Animated(name, title(scene), _caption(anim, fmt), path.name)


def _caption(anim: SceneAnimation, fmt: str) -> str:
    times = anim.times
    step = float(np.median(np.diff(times))) if len(times) > 1 else math.nan
    slow = PLAYBACK_FPS * step if np.isfinite(step) else math.nan
    runs = "; ".join(F._run_note(c.record) for c in anim.cols)
    parts = [
        f"{len(times)} frames from t = {times[0]:.3g} s to {times[-1]:.3g} s, one every "
        f"{step:.3g} s of simulated time, played at {PLAYBACK_FPS:g} frames/s "
        f"({slow:.3g} x real time).",
    ]
    if anim.polys:
        parts.append(
            "Top: the cloth, each triangle coloured by its aerodynamic pressure |F| / A "
            f"(one scale for all panels, 0 to {anim.p_norm.vmax:.3g} Pa)."
        )
    parts.append(
        f"{'Bottom' if anim.polys else 'Panels'}: wind speed in the horizontal slice at "
        f"z = {anim.cols[0].frames.slice_z:.3g} m (0 to {anim.u_norm.vmax:.3g} m/s)."
    )
    if any(c.frames.reached is not None for c in anim.cols):
        parts.append(
            F.ARRIVAL
            if anim.direction is not None
            else "Particle tracing: pale grey cells have not been reached by any gust particle."
        )
    parts.append(f"Runs: {runs}. Format: {fmt.upper()}.")
    return " ".join(parts)


PAPER_ORDER = ("flag", "two_flags_wall", "shirt", "opposing_sources")  # Figs. 3, 4/5, 6, §4.2.2


def _animate_scene(piece: tuple) -> Animated | F.Missing:
    """:func:`animate` of one ``(records, scene, folder)`` piece, in a worker process."""
    records, scene, folder = piece
    return animate(records, scene, folder, progress=False)


def _scene_order(records: Sequence[RunRecord]) -> list[str]:
    """The scenes among the complete runs, the paper's first (the validation problem left
    out)."""
    from windbench.report.validation import VALIDATION_SCENE

    scenes = {str(r.settings.get("scene")) for r in records if r.status == "complete"}
    scenes.discard(VALIDATION_SCENE)
    return sorted(scenes, key=lambda s: (PAPER_ORDER.index(s) if s in PAPER_ORDER else 9, s))


def start(records: Sequence[RunRecord], folder: Path, jobs: int = 1):
    """Start drawing one animation per scene over up to ``jobs`` processes; :func:`section`
    collects them, so that the report draws its other figures meanwhile."""
    from windbench.report.parallel import Batch

    pieces = [
        ([r for r in records if r.settings.get("scene") == s], s, folder)
        for s in _scene_order(records)
    ]
    return Batch(_animate_scene, pieces, jobs, 1)


def section(animations, place, regenerate: str, progress: bool):
    """The report's animation section from the :func:`start` ed ``animations``: one per
    scene, or one note when no run kept frames. ``place`` turns a Missing into a note;
    ``regenerate`` is the sentence that ends every caption."""
    from windbench.report.document import Section, Text, VideoRef

    intro = Text(
        "Each scene in motion, the backends side by side, from the frames the runs kept "
        "(`output.frames`; no physics is re-run). MP4 (H.264) plays in the page; "
        "`report.md` links the files."
    )
    results = animations.results("animations", progress)
    if results and all(isinstance(r, F.Missing) for r in results):
        note = F.Missing(
            "animations",
            "Animations",
            f"runs that keep frames, e.g. `windbench -m experiment=paper` or any run with "
            f"`{FRAMES_COMMAND}`",
        )
        return Section("Animations", [intro, place(note)])
    blocks = [intro]
    for r in results:
        if isinstance(r, Animated):
            blocks.append(VideoRef(r.name, r.title, f"{r.caption} {regenerate}", r.file))
        else:
            blocks.append(place(r))
    return Section("Animations", blocks)
