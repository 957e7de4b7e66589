"""Shared inputs of the photogrammetry tests: the real Caliterra subset (skipped when the shared data
folder is absent) and a small simulated survey; each SfM run happens once per session."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from ..once_per_session import once_per_session

from ..shared_images import shared_image_set

SIM_SEED = 7


def caliterra_dir() -> Path:
    return shared_image_set("caliterra_subset30")


@pytest.fixture(scope="session")
def caliterra_images() -> Path:
    d = caliterra_dir()
    if not d.is_dir() or not any(d.glob("*.jpg")):
        pytest.skip(f"shared data not available ({d})")
    return d


@pytest.fixture(scope="session")
def caliterra_sfm(caliterra_images, tmp_path_factory):
    from georef_core.photo.sfm import SfmOptions, run_sfm

    def make(folder):
        stages = []
        result = run_sfm(caliterra_images, folder, SfmOptions(), progress=lambda s, d, t: stages.append((s, d, t)))
        return result, stages

    return once_per_session(tmp_path_factory, "caliterra_sfm", make)


def _rendering_available() -> bool:
    if not all(importlib.util.find_spec(m) for m in ("open3d", "PIL", "piexif", "rasterio")):
        return False
    try:
        import open3d  # noqa: F401
    except Exception:  # noqa: BLE001  (open3d fails without the system libusb)
        return False
    return True


@pytest.fixture(scope="session")
def photo_sim(tmp_path_factory):
    if not _rendering_available():
        pytest.skip("open3d / Pillow / piexif / rasterio missing")
    from georef_core.sim import SimulationOptions, simulate_site

    # the same survey as tests/sim's small_sim (seed 7, small options): rendered once for both
    return once_per_session(tmp_path_factory, f"small_sim_seed{SIM_SEED}", lambda folder: simulate_site(
        folder, seed=SIM_SEED, options=SimulationOptions.small(), verbose=False))


@pytest.fixture(scope="session")
def sim_sfm(photo_sim, tmp_path_factory):
    from georef_core.photo.sfm import SfmOptions, run_sfm

    return run_sfm(photo_sim.out_dir / "images", tmp_path_factory.mktemp("sim_sfm"), SfmOptions(camera_model="OPENCV", refine_principal_point=True))
