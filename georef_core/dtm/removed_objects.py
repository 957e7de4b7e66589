"""What the ground filter removed: connected regions (8-neighbourhood) of non-ground DSM cells, with their
area, centre, height above the DTM and how smooth the ground around them is (the RMS of a plane fitted to a
ring of ground cells 1 m wide around each: a guide to how well the DTM under it is known)."""

from __future__ import annotations

import numpy as np
from scipy import ndimage


def removed_objects(nonground: np.ndarray, dsm: np.ndarray, dtm: np.ndarray, ground: np.ndarray, transform,
                    resolution_m: float, min_area_m2: float = 1.0, ring_m: float = 1.0, max_items: int = 500) -> dict:
    """Objects (regions of at least ``min_area_m2``) and spikes (smaller regions) of the non-ground mask.
    ``transform``: the raster's affine transform (cell -> E, N of its corner)."""
    labels, n = ndimage.label(nonground, structure=np.ones((3, 3), bool))
    cell_area = resolution_m * resolution_m
    if n == 0:
        return {"count": 0, "area_m2": 0.0, "largest_area_m2": 0.0, "spikes": 0, "spike_area_m2": 0.0, "items": []}
    counts = np.bincount(labels.ravel(), minlength=n + 1)
    is_object = counts * cell_area >= min_area_m2
    is_object[0] = False
    items = []
    slices = ndimage.find_objects(labels)
    ring_cells = max(1, int(round(ring_m / resolution_m)))
    for lab in np.flatnonzero(is_object)[:max_items]:
        sl = slices[lab - 1]
        pad = ring_cells + 1
        r0, r1 = max(0, sl[0].start - pad), min(labels.shape[0], sl[0].stop + pad)
        c0, c1 = max(0, sl[1].start - pad), min(labels.shape[1], sl[1].stop + pad)
        win = labels[r0:r1, c0:c1] == lab
        rr, cc = np.nonzero(win)
        above = (dsm[r0:r1, c0:c1] - dtm[r0:r1, c0:c1])[win]
        grown = ndimage.binary_dilation(win, iterations=ring_cells)
        ring = grown & ~win & ground[r0:r1, c0:c1]
        ring_rms = None
        if ring.sum() >= 6:
            yr, xr = np.nonzero(ring)
            zr = dsm[r0:r1, c0:c1][ring].astype(np.float64)
            A = np.column_stack([np.ones_like(xr, float), xr * resolution_m, yr * resolution_m])
            coef, *_ = np.linalg.lstsq(A, zr, rcond=None)
            ring_rms = round(float(np.sqrt(np.mean((zr - A @ coef) ** 2))), 4)
        e, nn = transform * (c0 + cc.mean() + 0.5, r0 + rr.mean() + 0.5)
        items.append({"id": int(lab), "centre_e_m": round(float(e), 3), "centre_n_m": round(float(nn), 3),
                      "area_m2": round(float(counts[lab] * cell_area), 3),
                      "max_height_m": round(float(np.nanmax(above)), 3) if np.isfinite(above).any() else None,
                      "ground_ring_rms_m": ring_rms})
    items.sort(key=lambda d: -d["area_m2"])
    spikes = ~is_object
    spikes[0] = False
    obj_area = float(counts[is_object].sum() * cell_area)
    return {"count": int(is_object.sum()), "area_m2": round(obj_area, 3),
            "largest_area_m2": round(float(counts[is_object].max() * cell_area), 3) if is_object.any() else 0.0,
            "spikes": int(spikes.sum()), "spike_area_m2": round(float(counts[spikes].sum() * cell_area), 3),
            "items": items}
