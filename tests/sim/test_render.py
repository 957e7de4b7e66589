"""Rendered survey: files, EXIF, projection round trip on the targets, DSM georeferencing, determinism."""

from __future__ import annotations

import datetime as dt
import hashlib
import json
import math

import numpy as np
import pytest

from georef_core.sim import CameraModel, CameraOptions

from .conftest import SEED, needs_rendering
from .helpers import refine_xcorner


def test_distortion_round_trip():
    cam = CameraModel.from_options(CameraOptions())
    u, v = np.meshgrid(np.linspace(0, cam.width - 1, 41), np.linspace(0, cam.height - 1, 31))
    rays = cam.pixel_to_ray(u, v)
    uv = cam.project(rays)
    assert np.max(np.abs(uv[..., 0] - u)) < 1e-8 and np.max(np.abs(uv[..., 1] - v)) < 1e-8
    # the distortion is not negligible at the corners
    xd, yd = (u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy
    x, y = cam.undistort_normalized(xd, yd)
    assert np.max(np.hypot(x - xd, y - yd)) * cam.fx > 10.0
    model, params = cam.colmap_params()
    assert model == "FULL_OPENCV" and params[2] == pytest.approx(cam.cx + 0.5)


@needs_rendering
def test_output_layout(small_sim):
    out = small_sim.out_dir
    n = small_sim.n_images
    assert 8 <= n <= 12
    assert sorted(p.name for p in (out / "images").iterdir()) == [e.name for e in small_sim.events]
    for name in ("trajectory.csv", "camera_poses.json", "intrinsics.json", "lever_arm_delay.json", "targets.csv",
                 "stockpiles.geojson", "dsm.tif", "site.json"):
        assert (out / "truth" / name).is_file(), name
    for name, files in (("rover", ["rover.obs"]), ("base", ["base.obs"]), ("nav", ["base.nav"])):
        assert sorted(p.name for p in (out / name).iterdir()) == files   # GNSS files only, as a user uploads them
    rows = (out / "events.csv").read_text().splitlines()
    assert rows[0].startswith("image,trigger_gps_time_s") and len(rows) == n + 1
    trig = [float(r.split(",")[1]) for r in rows[1:]]
    np.testing.assert_allclose(trig, [e.trigger_gps_time_s for e in small_sim.events], atol=1e-6)
    gcp = (out / "gcp" / "points.csv").read_text().splitlines()
    assert gcp[0] == "name,easting_m,northing_m,ellipsoidal_height_m,role"
    assert {r.split(",")[-1] for r in gcp[1:]} == {"control", "check"}
    poses = json.loads((out / "truth" / "camera_poses.json").read_text())
    assert len(poses["images"]) == n
    assert poses["delay_s"] == small_sim.options.flight.trigger_delay_s


@needs_rendering
def test_exif(small_sim):
    import piexif
    from PIL import Image

    from georef_core.sim.flight import gps_time_to_utc

    cam = small_sim.camera
    for e in small_sim.events[:3]:
        path = small_sim.out_dir / "images" / e.name
        with Image.open(path) as im:
            assert im.size == (cam.width, cam.height)
        ex = piexif.load(str(path))["Exif"]
        stamp = ex[piexif.ExifIFD.DateTimeOriginal].decode() + "." + ex[piexif.ExifIFD.SubSecTimeOriginal].decode()
        t = dt.datetime.strptime(stamp, "%Y:%m:%d %H:%M:%S.%f")
        utc = gps_time_to_utc(e.exposure_gps_time_s)
        assert 0 <= (utc - t).total_seconds() < 1e-3
        num, den = ex[piexif.ExifIFD.FocalLength]
        assert num / den == pytest.approx(cam.focal_mm, rel=1e-4)
        num, den = ex[piexif.ExifIFD.FocalPlaneXResolution]
        assert ex[piexif.ExifIFD.FocalPlaneResolutionUnit] == 3
        sensor_w_mm = cam.width / (num / den) * 10.0
        assert sensor_w_mm == pytest.approx(cam.sensor_size_mm[0], rel=1e-3)
        assert abs(ex[piexif.ExifIFD.FocalLengthIn35mmFilm] - cam.focal_35mm_equiv) <= 0.5


@needs_rendering
def test_targets_project_where_rendered(small_sim):
    """Project the known 3-D target centres with the truth pose + intrinsics and find the rendered
    checker centre in the JPEG near there: they agree to well under a pixel."""
    from PIL import Image

    site, cam = small_sim.site, small_sim.camera
    poses = json.loads((small_sim.truth_dir / "camera_poses.json").read_text())["images"]
    errs = []
    for p in poses:
        img = np.asarray(Image.open(small_sim.out_dir / "images" / p["name"]).convert("L"), dtype=float)
        c = np.array(p["camera_centre_enu_m"])
        R = np.array(p["R_cam_to_enu"])
        for t in site.targets:
            P = site.frame.site_to_enu(t.x, t.y, t.z)
            uv = cam.project_world(P[None], c, R)[0]
            if not (15 < uv[0] < cam.width - 15 and 15 < uv[1] < cam.height - 15):
                continue
            side_px = t.size_m * cam.fx / np.linalg.norm(P - c)
            q = refine_xcorner(img, uv + np.array([0.7, -0.6]), 0.3 * side_px)  # start off the answer
            assert q is not None
            errs.append(q - uv)
    errs = np.array(errs)
    assert len(errs) >= 2 * len(poses)
    assert np.max(np.hypot(errs[:, 0], errs[:, 1])) < 0.5
    assert np.sqrt(np.mean(errs**2)) < 0.15


@needs_rendering
def test_dsm_georeferenced(small_sim):
    import rasterio

    site = small_sim.site
    f = site.frame
    with rasterio.open(small_sim.truth_dir / "dsm.tif") as ds:
        assert ds.crs.to_epsg() == f.epsg
        pts = [(t.x + f.origin_e, t.y + f.origin_n) for t in site.targets]
        vals = np.array([v[0] for v in ds.sample(pts)])
        res = ds.res[0]
    # targets lie on (near-)flat ground: the cell value is the surface at the cell centre
    np.testing.assert_allclose(vals, [t.z for t in site.targets], atol=0.02 * res / 0.05)


@needs_rendering
def test_deterministic(small_sim, tmp_path):
    from georef_core.sim import simulate_site

    again = simulate_site(tmp_path / "again", seed=SEED, options=small_sim.options, verbose=False)

    def digests(root):
        return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
                for p in sorted(root.rglob("*")) if p.is_file()}

    a, b = digests(small_sim.out_dir), digests(again.out_dir)
    assert a.keys() == b.keys()
    assert [k for k in a if a[k] != b[k]] == []
    other = build_other(tmp_path)
    assert other != a["truth/trajectory.csv"]


def build_other(tmp_path):
    """A different seed gives a different survey (site and flight only, quick)."""
    from georef_core.sim import SimulationOptions, simulate_site

    o = SimulationOptions.small()
    o.write_images = False
    r = simulate_site(tmp_path / "other", seed=SEED + 1, options=o, verbose=False)
    return hashlib.sha256((r.truth_dir / "trajectory.csv").read_bytes()).hexdigest()


def test_small_options_image_count():
    from georef_core.sim import SimulationOptions, build_site, simulate_flight

    o = SimulationOptions.small()
    site = build_site(o.site, SEED)
    _, events, plan = simulate_flight(site, CameraModel.from_options(o.camera), o.flight, SEED)
    assert len(events) == 12 and len(plan.lines) == 2
    assert not math.isnan(plan.takeoff_ground_h)
