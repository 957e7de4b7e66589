"""Shared small simulated survey (12 images of 640 x 480), generated once per test session."""

from __future__ import annotations

import importlib.util

import pytest

from ..once_per_session import once_per_session

SEED = 7


def _have(mod: str) -> bool:
    return importlib.util.find_spec(mod) is not None


def rendering_available() -> bool:
    if not (_have("open3d") and _have("PIL") and _have("piexif") and _have("rasterio")):
        return False
    try:
        import open3d  # noqa: F401  (fails without the system libusb on Debian)
    except Exception:
        return False
    return True


needs_rendering = pytest.mark.skipif(not rendering_available(), reason="open3d / Pillow / piexif / rasterio missing")


@pytest.fixture(scope="session")
def small_sim(tmp_path_factory):
    if not rendering_available():
        pytest.skip("open3d / Pillow / piexif / rasterio missing")
    from georef_core.sim import SimulationOptions, simulate_site

    # the same survey as tests/photo's photo_sim (seed 7, small options): rendered once for both
    return once_per_session(tmp_path_factory, f"small_sim_seed{SEED}", lambda folder: simulate_site(
        folder, seed=SEED, options=SimulationOptions.small(), verbose=False))
