"""Shared inputs of the dense tests: the small simulated survey (12 images of 640 x 480, seed 1, no GNSS
files), its true orientations as an oriented-images file, and one dense run over it (once per session)."""

from __future__ import annotations

import importlib.util
import json

import pytest

from ..once_per_session import once_per_session

SEED = 1


def rendering_available() -> bool:
    if not all(importlib.util.find_spec(m) for m in ("open3d", "PIL", "piexif", "rasterio", "cv2", "laspy")):
        return False
    try:
        import open3d  # noqa: F401  (fails without the system libusb on Debian)
    except Exception:  # noqa: BLE001
        return False
    return True


def simulate_small_survey(tmp_path_factory, name: str, readout_s: float = 0.0):
    """The small simulated survey (seed SEED, no GNSS files), its camera with a rolling shutter of
    ``readout_s`` if given; rendered once per test session (tests only read it)."""
    if not rendering_available():
        pytest.skip("open3d / Pillow / piexif / rasterio / opencv / laspy missing")
    from georef_core.sim import SimulationOptions, simulate_site

    options = SimulationOptions.small()
    options.gnss = None
    if readout_s:
        options.camera = options.camera.rolling(readout_s)
    return once_per_session(tmp_path_factory, name,
                            lambda folder: simulate_site(folder, seed=SEED, options=options, verbose=False))


@pytest.fixture(scope="session")
def dense_sim(tmp_path_factory):
    return simulate_small_survey(tmp_path_factory, "dense_sim")


@pytest.fixture(scope="session")
def dense_run(dense_sim, tmp_path_factory):
    """(run folder, summary, progress calls) of run_dense on the simulator's true orientations."""
    from georef_core.photo.oriented_images import oriented_images_from_simulator_truth
    from georef_core.steps.dense import DenseOptions, run_dense

    def make(out):
        oriented_images_from_simulator_truth(dense_sim.out_dir).write(out / "oriented_images.json")
        calls = []
        summary = run_dense(out, DenseOptions(workers=2), progress=lambda s, d, t: calls.append((s, d, t)))
        return out, summary, calls

    return once_per_session(tmp_path_factory, "dense_run", make)


@pytest.fixture(scope="session")
def work_area_bounds(dense_sim):
    """(west, south, east, north) of the simulated work area in the project CRS."""
    site = json.loads((dense_sim.out_dir / "truth" / "site.json").read_text())
    f, wa = site["frame"], site["work_area_site_xy_m"]
    return (f["origin_E_m"] + wa[0][0], f["origin_N_m"] + wa[0][1], f["origin_E_m"] + wa[1][0],
            f["origin_N_m"] + wa[1][1])
