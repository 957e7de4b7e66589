"""Where checkerboard targets appear in an orthophoto, compared with their surveyed positions.

A 2 x 2 checker's centre is a saddle point of the image intensity; OpenCV's ``cornerSubPix`` finds it to a
fraction of a cell from a start a few cells away. The start is deliberately offset from the surveyed
position (so that a found centre is not just the start echoed back), and the four quadrants around the
surveyed centre along the target's own axes must show the checker pattern (diagonal quadrants alike,
neighbouring ones opposite), so that a shifted or blurred orthophoto is not credited with a target.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import rasterio


@dataclass
class TargetOffset:
    name: str
    de_m: float  # found - surveyed, easting
    dn_m: float
    pattern_ok: bool  # the checker pattern is at the surveyed position
    contrast: float  # |mean(dark diagonal) - mean(bright diagonal)| (grey levels)

    @property
    def offset_m(self) -> float:
        return float(np.hypot(self.de_m, self.dn_m))


def read_targets(path) -> list[dict]:
    """Rows of a targets CSV with ``name, easting_m, northing_m`` and optional ``rotation_deg``, ``size_m``
    (the simulator's truth/targets.csv)."""
    with Path(path).open() as f:
        return list(csv.DictReader(f))


def target_offsets(ortho_path, targets: list[dict], start_offset_m=(0.12, -0.10), window_px: int = 5) -> list[TargetOffset]:
    with rasterio.open(ortho_path) as ds:
        img = ds.read()
        T = ds.transform
    rgb = np.ascontiguousarray(np.transpose(img[:3], (1, 2, 0)))
    gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY).astype(np.float32)
    alpha = img[3] if img.shape[0] >= 4 else np.full(gray.shape, 255, np.uint8)
    h, w = gray.shape
    out = []
    for t in targets:
        e, n = float(t["easting_m"]), float(t["northing_m"])
        rot = np.radians(float(t.get("rotation_deg") or 0.0))
        size = float(t.get("size_m") or 1.0)
        q, inside = [], True
        for sx, sy in ((1, 1), (-1, 1), (-1, -1), (1, -1)):
            a, b = sx * size / 4, sy * size / 4
            c, r = ~T @ (e + a * np.cos(rot) - b * np.sin(rot), n + a * np.sin(rot) + b * np.cos(rot))
            ri, ci = int(np.floor(r)), int(np.floor(c))
            if not (0 <= ri < h and 0 <= ci < w) or alpha[ri, ci] == 0:
                inside = False
                break
            q.append(float(gray[ri, ci]))
        if not inside:
            out.append(TargetOffset(t["name"], float("nan"), float("nan"), False, 0.0))
            continue
        contrast = abs((q[0] + q[2]) - (q[1] + q[3])) / 2
        pattern_ok = abs(q[0] - q[2]) < 0.3 * contrast and abs(q[1] - q[3]) < 0.3 * contrast and contrast > 60
        c, r = ~T @ (e + start_offset_m[0], n + start_offset_m[1])
        start = np.array([[[c - 0.5, r - 0.5]]], np.float32)
        p = cv2.cornerSubPix(gray, start, (window_px, window_px), (-1, -1),
                             (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-4))[0, 0].astype(float)
        ef, nf = T @ (p[0] + 0.5, p[1] + 0.5)  # float64: map coordinates overflow float32's precision
        out.append(TargetOffset(t["name"], float(ef - e), float(nf - n), bool(pattern_ok), float(contrast)))
    return out
