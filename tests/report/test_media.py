"""Frames through the run loop, the animations made from them, Fig. 6 and the validation
section, on tiny runs (fixtures in conftest.py; test_browser.py opens the same report)."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")


import numpy as np  # noqa: E402
import pytest  # noqa: E402
import xarray as xr  # noqa: E402

from tests.report.tiny_runs import SHIRT, TINY, WALL, run_ok  # noqa: E402
from windbench.cli import compose_config  # noqa: E402
from windbench.errors import ConfigError  # noqa: E402
from windbench.report import animation, validation  # noqa: E402
from windbench.report.collect import find_runs, read_runs  # noqa: E402
from windbench.report.frames import open_frames, side_pressure  # noqa: E402
from windbench.simulate import prepare  # noqa: E402

pytestmark = pytest.mark.heavy  # runs the runs its animations are drawn from


def test_frames_are_kept_every_interval_and_agree_with_therun_ok(frame_runs):
    with xr.open_dataset(frame_runs / "wall_particles" / "windbench.nc") as ds:
        recorded = ds["frame_time"].values - ds.attrs["spinup"]  # after the spin-up
        np.testing.assert_allclose(recorded, [0.1, 0.2, 0.3], atol=1e-9)
        # the last frame is the last step: its slice is the last snapshot's layer
        z = float(ds["slice_wind"].attrs["slice_z"])
        layer = int(np.abs(ds["z"].values - z).argmin())
        np.testing.assert_array_equal(
            ds["slice_wind"].values[-1], ds["wind"].values[-1][:, :, layer, :]
        )
        # the per-triangle forces add up to each cloth's total at the same step
        owner = ds["vertex_cloth"].values[ds["cloth_triangles"].values[:, 0]]
        steps = np.searchsorted(ds["time"].values, ds["frame_time"].values - 1e-9)
        for k, n in enumerate(steps):
            tri = ds["triangle_force"].values[k]
            totals = np.stack([tri[owner == c].sum(axis=0) for c in range(ds.sizes["cloth"])])
            np.testing.assert_allclose(totals, ds["aero_force"].values[n], rtol=1e-12, atol=1e-12)
        # every reached cell of the slice lies inside the box around all reached cells
        x, y = np.meshgrid(ds["x"].values, ds["y"].values, indexing="ij")
        for reached, box in zip(ds["slice_reached"].values, ds["reached_box"].values, strict=True):
            assert reached.any()
            inside = (x >= box[0, 0]) & (x <= box[1, 0]) & (y >= box[0, 1]) & (y <= box[1, 1])
            assert inside[reached.astype(bool)].all()
        # the gust front moves downwind from frame to frame
        assert np.all(np.diff(ds["reached_box"].values[:, 1, 0]) > 0)
    with xr.open_dataset(frame_runs / "wall_global" / "windbench.nc") as ds:
        assert "slice_reached" not in ds  # the global field has no arrival


def test_a_run_keeps_no_frames_by_default(tmp_path):
    with xr.open_dataset(run_ok(tmp_path, *WALL, "wind=global", "sim.duration=0.1")) as ds:
        assert "frame" not in ds.dims and "slice_wind" not in ds


@pytest.mark.parametrize(
    ("override", "key"),
    [
        ("output.frames.interval=-0.1", "output.frames.interval"),
        ("output.frames.height=9", "output.frames.height"),
    ],
)
def test_bad_frame_settings_stop_before_any_work(override, key):
    with pytest.raises(ConfigError) as err:
        prepare(compose_config([*TINY, *WALL, override]))
    assert err.value.key == key


def test_a_shirt_in_the_global_wind_has_the_same_pressure_front_and_back_at_rest(tmp_path):
    """The global field has no lee: on a shirt that has not moved yet (first frame, no
    spin-up) every triangle sees the same wind, and the tube is mirror-symmetric front to
    back."""
    frames = open_frames(run_ok(tmp_path, *SHIRT, "wind=global", "sim.spinup=0"))
    front, back = side_pressure(frames.force[0], frames.positions[0], frames.triangles, [1, 0, 0])
    assert front > 1.0 and back == pytest.approx(front, rel=0.02)


def test_mp4_and_gif_hold_every_frame(tmp_path):
    imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg")
    frames = [np.full((48, 64, 3), 40 * k, dtype=np.uint8) for k in range(5)]
    mp4 = animation.encode(iter(frames), 5, tmp_path / "a", 10.0, "mp4", progress=False)
    reader = imageio_ffmpeg.read_frames(str(mp4))
    meta = next(reader)
    decoded = [np.frombuffer(f, np.uint8).reshape(48, 64, 3) for f in reader]
    assert meta["size"] == (64, 48) and meta["fps"] == 10.0 and len(decoded) == 5
    np.testing.assert_allclose([d.mean() for d in decoded], [40 * k for k in range(5)], atol=3)
    from PIL import Image

    gif = animation.encode(iter(frames), 5, tmp_path / "a", 10.0, "gif", progress=False)
    with Image.open(gif) as img:
        assert img.n_frames == 5 and img.size == (
            64 // animation.GIF_REDUCE,
            48 // animation.GIF_REDUCE,
        )
    with pytest.raises(ValueError, match="mp4 or gif"):
        animation.encode(iter(frames), 5, tmp_path / "a", 10.0, "avi", progress=False)


def test_the_report_plays_one_animation_per_scene_and_links_it(media_report):
    out = media_report.out
    html = (out / "index.html").read_text()
    md = (out / "report.md").read_text()
    for scene in ("two_flags_wall", "shirt"):
        video = out / "figures" / f"anim_{scene}.mp4"
        assert video.stat().st_size > 1000
        assert (
            f'<video controls loop muted playsinline preload="metadata" src="figures/anim_{scene}.mp4">'
            in html
        )
        assert f"(figures/anim_{scene}.mp4)" in md
    assert "fig6_shirt" in media_report.drawn
    assert "Regenerate: `windbench-report" in md
    # a particle run recorded before its wind crossed the domain is not drawn as lee: it
    # has no steady window, and the report lists it as unsettled with the reason
    assert "unsettled" in md and "no steady window" in md


def test_without_frames_the_report_says_how_to_get_animations(tmp_path):
    run_ok(tmp_path / "runs" / "a", *WALL, "wind=global", "sim.duration=0.1")
    records = read_runs(find_runs([tmp_path / "runs"]), progress=False)
    notes = []

    def place(missing):
        notes.append(missing)
        return missing

    sec = animation.section(animation.start(records, tmp_path / "fig"), place, "", progress=False)
    assert [n.name for n in notes] == ["animations"] and "output.frames" in notes[0].needs
    assert len(sec.blocks) == 2 and not (tmp_path / "fig").exists()


def test_start_up_poiseuille_flow_goes_from_rest_to_the_parabola():
    s = np.linspace(0.0, 1.0, 41)
    u_max = 0.8 / (8 * 0.1)
    start = validation.poiseuille_start_up(s, 0.0, 1.0, 0.8, 0.1)
    assert np.abs(start).max() < 1e-5 * u_max  # the series of the parabola, truncated
    steady = validation.poiseuille_start_up(s, 100.0, 1.0, 0.8, 0.1)
    np.testing.assert_allclose(steady, 0.8 / 0.2 * s * (1 - s), atol=1e-12)
    # in between, the slowest mode: 32/pi^3 exp(-pi^2 nu t / H^2) of u_max at mid-channel
    mid = validation.poiseuille_start_up(np.array([0.5]), 2.0, 1.0, 0.8, 0.1)[0]
    assert u_max - mid == pytest.approx(validation.transient_left(2.0, 1.0, 0.1) * u_max, rel=1e-3)


def test_poiseuille_through_the_run_loop_has_the_known_error(tmp_path):
    """Against u(y, t) the error of the run is the no-slip ghost value's (h/H)^2 u_max."""
    path = run_ok(
        tmp_path / "p8", "experiment=validation_ns", "grid.resolution=8", "sim.duration=4"
    )
    records = read_runs([path], progress=False)
    table = validation.poiseuille_table(records)
    row = table.iloc[0]
    assert row["cells across"] == 8
    assert row["max error / u_max"] == pytest.approx(row["(h/H)^2"], rel=0.1)
    blocks = []
    sec = validation.section(records, [tmp_path], lambda r: blocks.append(r) or r)
    names = [b.name for b in blocks]
    assert sec is not None and "validation_poiseuille" in names
    if (validation.TREE_RESULTS / validation.RESULTS_FILE).is_file():
        assert "validation_taylor_green" in names  # found in this source tree
