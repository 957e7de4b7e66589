"""Choosing frames in a binary log (UBX, RTCM 3) once every candidate's checksum is known: the valid
frames taken greedily in stream order, and the candidates that lie inside an accepted frame (chance
sync bytes in its payload, not corrupt frames)."""

from __future__ import annotations

import numpy as np


def take_frames_in_order(cand: np.ndarray, end: np.ndarray, ok: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(indices of the accepted frames, mask of the candidates inside an accepted frame).

    cand: (C,) start offsets, sorted; end: (C,) end offsets (exclusive); ok: (C,) checksum valid. A valid
    candidate that starts inside an earlier accepted frame is not taken."""
    good = np.flatnonzero(ok)
    g_start, g_end = cand[good], end[good]
    if len(good) > 1 and np.any(g_start[1:] < g_end[:-1]):
        keep = np.zeros(len(good), dtype=bool)
        last_end = -1
        for k in range(len(good)):
            if g_start[k] >= last_end:
                keep[k] = True
                last_end = g_end[k]
        good = good[keep]
    if not len(good):
        return good, np.zeros(len(cand), dtype=bool)
    k = np.searchsorted(cand[good], cand, side="right") - 1
    inside = (k >= 0) & (cand < end[good][np.maximum(k, 0)])
    return good, inside
