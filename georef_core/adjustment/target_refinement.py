"""Sub-pixel refinement of clicked target centres.

Ground targets are usually black/white checkers whose centre is a saddle point of the image
intensity. A surveyor's click is good to a few tenths of a pixel; OpenCV's saddle-point refinement
(cornerSubPix: the point where the image gradients in a small window are orthogonal to the lines
towards it) brings it to a few hundredths. A refinement is kept only when it moves the click by less
than ``max_shift_px`` and the point is a saddle (negative Hessian determinant of the smoothed image),
so painted marks of other shapes keep their clicked positions.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def refine_measurements(image_dir, measurements, window_px: int = 5, max_shift_px: float = 1.5) -> tuple[int, int]:
    """Refine ``ImageMeasurement.uv_px`` in place; returns (refined, kept as clicked)."""
    import cv2
    from PIL import Image

    by_image: dict[str, list] = {}
    for m in measurements:
        by_image.setdefault(m.image, []).append(m)
    n_ref = n_keep = 0
    for name, ms in by_image.items():
        path = Path(image_dir) / name
        if not path.is_file():
            n_keep += len(ms)
            continue
        gray = np.asarray(Image.open(path).convert("L"), dtype=np.float32)
        smooth = cv2.GaussianBlur(gray, (0, 0), 1.0)
        h, w = gray.shape
        for m in ms:
            u, v = float(m.uv_px[0]), float(m.uv_px[1])
            if not (window_px + 2 <= u < w - window_px - 2 and window_px + 2 <= v < h - window_px - 2):
                n_keep += 1
                continue
            pt = np.array([[[u, v]]], dtype=np.float32)
            crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
            ref = cv2.cornerSubPix(gray, pt.copy(), (window_px, window_px), (-1, -1), crit)[0, 0]
            shift = float(np.hypot(ref[0] - u, ref[1] - v))
            iu, iv = int(round(ref[0])), int(round(ref[1]))
            if shift > max_shift_px or not _is_saddle(smooth, iu, iv):
                n_keep += 1
                continue
            m.uv_px = np.array([float(ref[0]), float(ref[1])])
            n_ref += 1
    return n_ref, n_keep


def _is_saddle(img: np.ndarray, u: int, v: int, step: int = 2) -> bool:
    if not (step <= u < img.shape[1] - step and step <= v < img.shape[0] - step):
        return False
    c = img[v, u]
    fxx = img[v, u + step] - 2 * c + img[v, u - step]
    fyy = img[v + step, u] - 2 * c + img[v - step, u]
    fxy = (img[v + step, u + step] - img[v + step, u - step] - img[v - step, u + step] + img[v - step, u - step]) / 4
    return fxx * fyy - fxy * fxy < 0
