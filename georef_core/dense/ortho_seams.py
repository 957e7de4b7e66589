"""Seamlines and multi-band blending of an orthophoto tile.

**Labels.** Each ortho cell first takes its most nadir visible view (the view whose centre ground point is
nearest; ``orthophoto.py``): a Voronoi partition of the views' centre points cut by visibility. Near the
boundary between two regions, in a band where the second-best view is less than ``band_m`` farther (in
centre-point distance) than the best, the seam is moved onto a path where the two views agree: a
marker-based watershed. Each view floods the band from its cells outside it over an elevation that is
high where a seam is wanted; a cell's cost for a view is the lowest possible highest elevation on a path
from that view's cells (minimax path cost, computed by grey-level reconstruction: iterated erosions,
``minimax_cost``), and a band cell goes to its second view only where that view's cost is strictly lower
than the first's; the floods so meet along the crest of

    elevation = 1 - 0.97 min(|Y1 - Y2| / 8, 1) - 0.03 (d2 - d1) / band_m

(Y the compensated luminances of the best and second views, smoothed over ~1.5 cells; d the centre-point
distances): seams follow low colour differences (where the two images agree: flat ground, low contrast,
no relief displacement) and, where all is alike, stay near the Voronoi boundary (the nadir-most choice).
Where the crest has a lower pass, the cells beyond it above the pass level
are reachable at equal cost from both sides and keep the nadir-most view. The erosions are vectorised
(OpenCV) and bounded (``max_iterations``: paths of up to that many cells); a graph cut with alpha-expansion
would give a globally optimal seam for such costs but needs a max-flow library and several passes per
label. A band cell only ever takes one of its two visible views.

**Blending** (Burt & Adelson 1983). With C the hard composite (each cell from its label's view) and, for
every label l of the tile, D_l = I_l - C on the cells within ``reach`` cells of l's region (I_l = view l
resampled there, where it sees the cell; 0 elsewhere, tapered to 0 over the outer third of the reach),
the blended tile is

    B = C + collapse( sum_l  G_i(M_l) * L_i(D_l) )

with M_l the indicator of l's region, G_i its Gaussian pyramid and L_i the Laplacian pyramid, levels i =
0..levels: the same as blending the views' Laplacian pyramids with the Gaussian pyramids of the masks,
since the masks sum to 1. Fine detail switches within a cell or two of the seam, coarse brightness is mixed
over ~2^levels cells. Cells away from seams are C exactly.
"""

from __future__ import annotations

import cv2
import numpy as np

DIFF_SCALE_DN = 8.0  # luminance difference (8-bit levels) above which a cell is as bad for a seam as any


def luminance(rgb: np.ndarray) -> np.ndarray:
    return rgb[..., 0] * 0.299 + rgb[..., 1] * 0.587 + rgb[..., 2] * 0.114


def minimax_cost(elevation: np.ndarray, seeds: np.ndarray, max_iterations: int) -> np.ndarray:
    """Per cell, the least possible highest elevation on a 4-connected path from a seed cell (0 on seeds,
    inf where ``elevation`` is inf or unreachable): grey-level reconstruction by erosion, iterated until
    stable or ``max_iterations``."""
    cross = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
    C = np.where(seeds, 0.0, np.inf).astype(np.float32)
    for it in range(max_iterations):
        Cn = np.maximum(elevation, cv2.erode(C, cross, borderType=cv2.BORDER_CONSTANT, borderValue=np.inf))
        Cn[seeds] = 0.0
        if it % 8 == 7 and np.array_equal(Cn, C):
            break
        C = Cn
    return C


def refine_seams(label1: np.ndarray, label2: np.ndarray, margin: np.ndarray, lum1: np.ndarray,
                 lum2: np.ndarray, in_band: np.ndarray, band: float, valid: np.ndarray,
                 max_iterations: int = 96, scale: int = 2) -> np.ndarray:
    """Labels (2-D, view indices, -1 where no view) after moving seams onto low-difference paths.

    label1/label2: best and second visible view per cell (-1: none); margin: d2 - d1 (same unit as band);
    lum1/lum2: their luminances; in_band: cells whose label may change; valid: cells with a view."""
    out = np.where(valid, label1, -1)
    if not in_band.any():
        return out
    diff = np.where(in_band, np.abs(lum1 - lum2), 0.0).astype(np.float32)
    wsum = cv2.GaussianBlur(in_band.astype(np.float32), (0, 0), 1.5)
    diff = cv2.GaussianBlur(diff, (0, 0), 1.5) / np.maximum(wsum, 1e-3)
    s = np.clip(diff / DIFF_SCALE_DN, 0.0, 1.0)
    p = np.clip(margin / band, 0.0, 1.0)
    elev = np.where(in_band, 1.0 - 0.97 * s - 0.03 * p, np.inf).astype(np.float32)
    # each view floods the band from its own cells outside it; a band cell goes to its second view when
    # that view's flood reaches it over a strictly lower crest than the first view's (ties: the nadir-most)
    rows, cols = np.nonzero(in_band)
    r0, r1, c0, c1 = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
    win = (slice(max(0, r0 - 1), r1 + 1), slice(max(0, c0 - 1), c1 + 1))
    e, l1, l2, vb, ib = elev[win], label1[win], label2[win], valid[win], in_band[win]
    # the floods run on a grid coarser by ``scale`` (the seam is placed to that many cells)
    k = max(1, int(scale))
    ec = cv2.resize(np.where(ib, e, 1.0).astype(np.float32), ((e.shape[1] + k - 1) // k, (e.shape[0] + k - 1) // k),
                    interpolation=cv2.INTER_AREA) if k > 1 else e
    l1c, l2c, vbc, ibc = l1[::k, ::k], l2[::k, ::k], vb[::k, ::k], ib[::k, ::k]
    ec = ec[:l1c.shape[0], :l1c.shape[1]]
    cost1 = np.full(e.shape, np.inf, np.float32)
    cost2 = np.full(e.shape, np.inf, np.float32)
    for lab in np.unique(np.concatenate([l1[ib], l2[ib]])):
        if lab < 0:
            continue
        seeds = vbc & ~ibc & (l1c == lab)
        if not seeds.any():
            continue
        reach = (l1c == lab) | (l2c == lab)
        near = cv2.dilate(reach.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        C = minimax_cost(np.where(seeds, 0.0, np.where(near & ibc, ec, np.inf)).astype(np.float32), seeds,
                         max_iterations)
        C = np.repeat(np.repeat(C, k, 0), k, 1)[:e.shape[0], :e.shape[1]] if k > 1 else C
        cost1 = np.where(ib & (l1 == lab), C, cost1)
        cost2 = np.where(ib & (l2 == lab), C, cost2)
    take2 = ib & (l2 >= 0) & (cost2 < cost1 - 1e-6)
    sub = out[win]
    sub[take2] = l2[take2]
    out[win] = sub
    return out


def _pyramid_sizes(shape: tuple[int, int], levels: int) -> list[tuple[int, int]]:
    sizes = [shape]
    for _ in range(levels):
        h, w = sizes[-1]
        if h < 2 or w < 2:
            break
        sizes.append(((h + 1) // 2, (w + 1) // 2))
    return sizes


def multiband_blend(composite: np.ndarray, labels: np.ndarray, differences: dict[int, np.ndarray],
                    levels: int) -> np.ndarray:
    """B = C + collapse(sum_l G(M_l) L(D_l)) (module docstring). composite (h, w, 3) float32; labels (h, w)
    int; differences: label -> D_l (h, w, 3) float32."""
    if not differences:
        return composite
    sizes = _pyramid_sizes(labels.shape, levels)
    acc = [np.zeros(s + (3,), np.float32) for s in sizes]
    for lab, D in differences.items():
        m = (labels == lab).astype(np.float32)
        g = D
        gm = m
        for i in range(len(sizes)):
            if i + 1 < len(sizes):
                h, w = sizes[i + 1]
                g_next = cv2.pyrDown(g, dstsize=(w, h))
                lap = g - cv2.pyrUp(g_next, dstsize=(sizes[i][1], sizes[i][0]))
            else:
                lap = g
            acc[i] += lap * gm[..., None]
            if i + 1 < len(sizes):
                h, w = sizes[i + 1]
                g = g_next
                gm = cv2.pyrDown(gm, dstsize=(w, h))
    out = acc[-1]
    for i in range(len(sizes) - 2, -1, -1):
        out = cv2.pyrUp(out, dstsize=(sizes[i][1], sizes[i][0])) + acc[i]
    return composite + out
