"""Quick-look PNGs of the dense products: hillshaded, colour-coded DSM and orthophoto thumbnail."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import rasterio


def _fit(img: np.ndarray, max_size: int) -> np.ndarray:
    h, w = img.shape[:2]
    s = min(1.0, max_size / max(h, w))
    if s < 1.0:
        img = cv2.resize(img, (max(1, round(w * s)), max(1, round(h * s))), interpolation=cv2.INTER_AREA)
    return img


def hillshade(dsm: np.ndarray, resolution_m: float, azimuth_deg: float = 315.0, altitude_deg: float = 45.0) -> np.ndarray:
    """Lambertian hillshade in 0..1 (NaN where the DSM is NaN); azimuth clockwise from north."""
    z = np.where(np.isfinite(dsm), dsm, np.nanmedian(dsm))
    dzdy, dzdx = np.gradient(z, resolution_m)  # rows go south: dz/dnorth = -dzdy
    nx, ny, nz = -dzdx, dzdy, np.ones_like(z)
    norm = np.sqrt(nx * nx + ny * ny + nz * nz)
    az, alt = np.radians(azimuth_deg), np.radians(altitude_deg)
    sx, sy, sz = np.sin(az) * np.cos(alt), np.cos(az) * np.cos(alt), np.sin(alt)
    shade = np.clip((nx * sx + ny * sy + nz * sz) / norm, 0, 1)
    shade[~np.isfinite(dsm)] = np.nan
    return shade


def dsm_preview_png(dsm_path, png_path, max_size: int = 1200, exaggeration: float = 2.0) -> Path:
    """Colour-coded heights (2nd-98th percentile) modulated by a hillshade; no-data white."""
    with rasterio.open(dsm_path) as ds:
        dsm = ds.read(1, masked=True).filled(np.nan).astype(np.float64)
        res = abs(ds.transform.a)
    s = min(1.0, max_size / max(dsm.shape))
    if s < 1.0:  # shade at the preview's resolution (block mean), not at the raster's
        k = int(np.ceil(1.0 / s))
        h, w = (dsm.shape[0] // k) * k, (dsm.shape[1] // k) * k
        with np.errstate(all="ignore"):
            import warnings

            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                dsm = np.nanmean(dsm[:h, :w].reshape(h // k, k, w // k, k), axis=(1, 3))
        res *= k
    shade = hillshade(dsm * exaggeration, res)
    valid = np.isfinite(dsm)
    lo, hi = np.percentile(dsm[valid], [2, 98]) if valid.any() else (0.0, 1.0)
    t = np.clip((np.where(valid, dsm, lo) - lo) / max(hi - lo, 1e-6), 0, 1)
    colour = cv2.applyColorMap((t * 255).astype(np.uint8), cv2.COLORMAP_TURBO).astype(np.float64)
    img = colour * (0.35 + 0.65 * np.nan_to_num(shade, nan=1.0))[..., None]
    img[~valid] = 255
    img = _fit(np.clip(img, 0, 255).astype(np.uint8), max_size)
    png_path = Path(png_path)
    png_path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(png_path), img, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    return png_path


def ortho_preview_png(ortho_path, png_path, max_size: int = 1200) -> Path:
    """RGB thumbnail (transparent cells white), read from the COG's overviews when small enough."""
    with rasterio.open(ortho_path) as ds:
        s = min(1.0, max_size / max(ds.width, ds.height))
        out_shape = (ds.count, max(1, round(ds.height * s)), max(1, round(ds.width * s)))
        data = ds.read(out_shape=out_shape, resampling=rasterio.enums.Resampling.average)
        alpha = data[3] if ds.count >= 4 else ds.dataset_mask(out_shape=out_shape[1:])
    img = np.transpose(data[:3], (1, 2, 0))[:, :, ::-1].astype(np.float64)
    a = (alpha.astype(np.float64) / 255.0)[..., None]
    img = img * a + 255.0 * (1 - a)
    png_path = Path(png_path)
    png_path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(png_path), np.clip(img, 0, 255).astype(np.uint8), [cv2.IMWRITE_PNG_COMPRESSION, 9])
    return png_path
