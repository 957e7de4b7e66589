"""Compiled (numba) decoding of RINEX observation fields: 16 characters, an F14.3 value then the LLI and SSI
digits (rinex_obs.py reads the files and handles every other layout on its slow path)."""

from __future__ import annotations

import numpy as np
from numba import njit

_SPACE, _MINUS, _DOT, _ZERO, _NINE = 32, 45, 46, 48, 57


@njit(cache=True)
def _is_flag(ch):
    return ch == _SPACE or (_ZERO <= ch <= _NINE)


@njit(cache=True)
def decode_fields(c):
    """(n, 16) uint8 fields -> values (NaN where blank or 0.000), LLI, SSI (the low 4 bits of columns 15 and 16:
    blank -> 0) and a mask of the fields not in F14.3 layout (right-aligned: blanks, an optional minus sign,
    up to 10 digits, the point in column 11, 3 decimals; flags blank or a digit), left to the caller."""
    n = c.shape[0]
    values = np.full(n, np.nan)
    lli = np.empty(n, np.uint8)
    ssi = np.empty(n, np.uint8)
    odd = np.zeros(n, np.bool_)
    for k in range(n):
        lli[k] = c[k, 14] & 15
        ssi[k] = c[k, 15] & 15
        if not (_is_flag(c[k, 14]) and _is_flag(c[k, 15])):
            odd[k] = True
            continue
        i = 0
        while i < 14 and c[k, i] == _SPACE:
            i += 1
        if i == 14:
            continue  # blank
        neg = c[k, i] == _MINUS
        if neg:
            i += 1
        thousandths = 0
        ok = c[k, 10] == _DOT and i <= 10
        for j in range(i, 14):
            if j == 10:
                continue
            ch = c[k, j]
            if not (_ZERO <= ch <= _NINE):
                ok = False
                break
            thousandths = thousandths * 10 + (np.int64(ch) - _ZERO)
        if not ok:
            odd[k] = True
            continue
        if thousandths != 0:
            v = thousandths / 1000.0
            values[k] = -v if neg else v
    return values, lli, ssi, odd
