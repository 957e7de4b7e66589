"""Large windows stream from the file in row strips: forcing that path on a small DSM (strips of a few
rows, any alignment) gives the in-memory results for every kind of base, and falls back to memory to
fill holes."""

from __future__ import annotations

import numpy as np
import pytest

import georef_core.volumes.volume as volume_module
from georef_core.volumes import NoiseModel, compute_volume, read_polygons

from .synthetic import E0, N0, circle, cone_height, write_dsm, write_geojson

C = (E0 + 12.3, N0 + 11.7)
MODEL = NoiseModel(0.03, 0.02, 0.5)


def test_strips_equal_memory(tmp_path, monkeypatch):
    def f(E, N):
        z = 50 + 0.03 * (E - E0) + cone_height(*C, 6.0, 3.0)(E, N)
        return np.where(np.hypot(E - C[0] - 2, N - C[1]) < 0.3, -9999.0, z)

    dsm = write_dsm(tmp_path / "d.tif", f, (25, 24), 0.1, nodata=-9999.0, tile=16)  # 16-row file blocks
    ground = write_dsm(tmp_path / "g.tif", lambda E, N: 50 + 0.03 * (E - E0) + 0 * N, (25, 24), 0.25)
    poly = read_polygons(write_geojson(tmp_path / "p.geojson", {"p": circle(*C, 6.5)}))[0]
    bases = ["lowest", "mean", "plane", "tin", "elevation:50", f"surface:{ground}"]
    mem = {b: compute_volume(dsm, poly, b, noise=MODEL) for b in bases}
    monkeypatch.setattr(volume_module, "IN_MEMORY_CELLS", 0)
    monkeypatch.setattr(volume_module, "STRIP_CELLS", 1000)  # strips of a few rows
    calls = []
    real = volume_module.Integrator.add
    monkeypatch.setattr(volume_module.Integrator, "add", lambda self, z, r0, *a: (calls.append((r0, len(z))),
                                                                               real(self, z, r0, *a)))
    for b in bases:
        s = compute_volume(dsm, poly, b, noise=MODEL)
        for k in ("cut_m3", "fill_m3", "net_m3", "area_m2", "filled_nodata_m2"):
            assert getattr(s, k) == pytest.approx(getattr(mem[b], k), rel=1e-9, abs=1e-9), (b, k)
        assert s.uncertainty["sigma_m3"] == pytest.approx(mem[b].uncertainty["sigma_m3"], rel=1e-6)
        assert s.filled_nodata_m2 > 0
    starts = sorted({r0 for r0, _ in calls})
    assert len(starts) > 5 and max(n for _, n in calls) <= 144  # many strips (then one in-memory pass per fill)
