"""GDAL's 4-sample bilinear warp of a tile from an affine mapping, as a numba kernel (tiles.render.RgbTileDrawer).

Each tile pixel centre (column + 0.5, row + 0.5) maps to the source window's pixel coordinates by the affine
(sx = a col + b row + c, sy = d col + e row + f). As GDAL's warper (gdalwarpkernel.cpp, GWKBilinearResample4Sample
and its no-mask form): a centre with sx or sy below 0, or whose truncated coordinate is at or beyond the size, is
left as it is (0); the taps are floor(s - 0.5) and the next, the first weighted 1.5 - (s - tap); with all four taps
inside the source the value is ((ul rx + ur (1 - rx)) ry + (ll rx + lr (1 - rx)) (1 - ry)), otherwise the taps
inside are summed with their weights and divided by the weights' sum (nothing written below 1e-5)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def bilinear_4_sample(src, a, b, c, d, e, f, out):
    """src (bands, h, w) float32, out (bands, n, n) float32 (written where a centre maps inside the source)."""
    bands, h, w = src.shape
    n_rows, n_cols = out.shape[1], out.shape[2]
    for r in range(n_rows):
        yc = r + 0.5
        for col in range(n_cols):
            xc = col + 0.5
            sx = a * xc + b * yc + c
            sy = d * xc + e * yc + f
            if sx < 0.0 or sy < 0.0 or int(sx + 1e-10) >= w or int(sy + 1e-10) >= h:
                continue
            ix = int(math.floor(sx - 0.5))
            iy = int(math.floor(sy - 0.5))
            rx = 1.5 - (sx - ix)
            ry = 1.5 - (sy - iy)
            if ix >= 0 and ix + 1 < w and iy >= 0 and iy + 1 < h:
                for k in range(bands):
                    v = ((np.float64(src[k, iy, ix]) * rx + np.float64(src[k, iy, ix + 1]) * (1.0 - rx)) * ry
                         + (np.float64(src[k, iy + 1, ix]) * rx + np.float64(src[k, iy + 1, ix + 1]) * (1.0 - rx))
                         * (1.0 - ry))
                    out[k, r, col] = v
                continue
            for k in range(bands):
                acc = 0.0
                wsum = 0.0
                for dy in range(2):
                    yy = iy + dy
                    if yy < 0 or yy >= h:
                        continue
                    wy = ry if dy == 0 else 1.0 - ry
                    for dx in range(2):
                        xx = ix + dx
                        if xx < 0 or xx >= w:
                            continue
                        wx = rx if dx == 0 else 1.0 - rx
                        acc += np.float64(src[k, yy, xx]) * wx * wy
                        wsum += wx * wy
                if wsum >= 1e-5:
                    out[k, r, col] = acc / wsum


@njit(cache=True, nogil=True)
def premultiplied_to_rgba(dst, out):
    """render_tile_rgba's last step in float32 as numpy does it: dst (4, n, n) premultiplied colour and alpha
    (0..255) -> out (n, n, 4) uint8: colour = dst * 255 / alpha (0 where alpha is 0), rounded half to even and
    clipped; alpha 255 where it is at least 127.5, else 0."""
    n_rows, n_cols = dst.shape[1], dst.shape[2]
    k255 = np.float32(255.0)
    tiny = np.float32(1e-6)
    for r in range(n_rows):
        for col in range(n_cols):
            alpha = dst[3, r, col]
            for k in range(3):
                v = np.float32(0.0)
                if alpha > 0:
                    v = np.float32(np.float32(dst[k, r, col] * k255) / max(alpha, tiny))
                v = np.float32(np.rint(v))
                out[r, col, k] = np.uint8(min(max(v, np.float32(0.0)), k255))
            out[r, col, 3] = np.uint8(255) if alpha >= 127.5 else np.uint8(0)
