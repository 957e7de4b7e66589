"""Compiled (numba) decoding of RINEX observation fields: 16 characters, an F14.3 value then the LLI and SSI
digits (rinex_obs.py reads the files and handles every other layout on its slow path)."""

from __future__ import annotations

import numpy as np
from .kernel_loader import njit

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


@njit(cache=True)
def _small_int(buf, a, b):
    """Value of buf[a:b] written as blanks then digits (at least one), else -1."""
    i = a
    while i < b and buf[i] == _SPACE:
        i += 1
    if i == b:
        return -1
    v = 0
    while i < b:
        ch = buf[i]
        if not (_ZERO <= ch <= _NINE):
            return -1
        v = v * 10 + (np.int64(ch) - _ZERO)
        i += 1
    return v


@njit(cache=True)
def _seconds(buf, a, b):
    """Value of buf[a:b] written as blanks, digits, a point and digits (F11.7), else -1.0. Integer mantissa
    over a power of ten: both exact, so the division rounds as Python's float() of the text does."""
    i = a
    while i < b and buf[i] == _SPACE:
        i += 1
    mantissa = 0
    digits = 0
    decimals = -1
    while i < b:
        ch = buf[i]
        if ch == _DOT and decimals < 0:
            decimals = 0
        elif _ZERO <= ch <= _NINE:
            mantissa = mantissa * 10 + (np.int64(ch) - _ZERO)
            digits += 1
            if decimals >= 0:
                decimals += 1
        else:
            return -1.0
        i += 1
    if digits == 0 or digits > 15:
        return -1.0
    return mantissa / 10.0 ** max(decimals, 0)


@njit(cache=True)
def scan_rinex2_epochs(buf, starts, ends, i, n_lines, lines_per_record):
    """Walk the RINEX 2 data section from line i over the regular epochs: epoch records with flag 0 or 1,
    readable time and satellite count, and all their lines before line n_lines - 1 (the last epoch, which
    may be truncated, is left to the caller). Stops at the first line that is anything else (an event or
    header record, a malformed line, the file's end) and returns where, so that the caller handles it with
    its error messages and carries on. buf: the file's bytes; starts / ends: each line's byte span.

    Returns (next line, epoch line indices, flags, satellite counts, first record lines, time fields (k, 6)
    as float, satellite identifiers (3 bytes per record, concatenated))."""
    cap = max(n_lines - i, 0)
    at = np.empty(cap, np.int64)
    flags = np.empty(cap, np.int64)
    counts = np.empty(cap, np.int64)
    first = np.empty(cap, np.int64)
    fields = np.empty((cap, 6))
    # an epoch of n satellites takes at least n + 1 of the lines walked, so 3 bytes a line always suffice
    sats = np.empty(3 * cap, np.uint8)
    n_sats_text = 0
    k = 0
    while i < n_lines:
        a, b = starts[i], ends[i]
        blank = True
        for j in range(a, b):
            ch = buf[j]
            if not (ch == _SPACE or ch == 9 or ch == 11 or ch == 12 or ch == 13):
                blank = False
                break
        if blank:
            i += 1
            continue
        if b - a < 32 or buf[a] != _SPACE:
            break
        flag = _small_int(buf, a + 26, a + 29)
        if flag == -1:
            blank_flag = True
            for j in range(a + 26, a + 29):
                if buf[j] != _SPACE:
                    blank_flag = False
            if not blank_flag:
                break
            flag = 0
        if flag > 1:
            break
        n = _small_int(buf, a + 29, a + 32)
        if n < 0:
            break
        n_cont = (n - 1) // 12 if n > 0 else 0
        first_obs = i + 1 + n_cont
        end = first_obs + n * lines_per_record
        if end >= n_lines:
            break
        yy = _small_int(buf, a + 1, a + 3)
        month = _small_int(buf, a + 4, a + 6)
        day = _small_int(buf, a + 7, a + 9)
        hour = _small_int(buf, a + 10, a + 12)
        minute = _small_int(buf, a + 13, a + 15)
        sec = _seconds(buf, a + 15, a + 26)
        if yy < 0 or month < 0 or day < 0 or hour < 0 or minute < 0 or sec < 0.0:
            break
        written = 0
        for line in range(i, first_obs):
            la, lb = starts[line], ends[line]
            for col in range(32, 68):
                if written == 3 * n:
                    break
                p = la + col
                sats[n_sats_text + written] = buf[p] if p < lb else _SPACE
                written += 1
        while written < 3 * n:
            sats[n_sats_text + written] = _SPACE
            written += 1
        n_sats_text += 3 * n
        at[k] = i
        flags[k] = flag
        counts[k] = n
        first[k] = first_obs
        fields[k, 0] = yy + (1900 if yy >= 80 else 2000)
        fields[k, 1] = month
        fields[k, 2] = day
        fields[k, 3] = hour
        fields[k, 4] = minute
        fields[k, 5] = sec
        k += 1
        i = end
    return i, at[:k], flags[:k], counts[:k], first[:k], fields[:k], sats[:n_sats_text]


@njit(cache=True)
def pad_rows(buf, starts, ends, rows, width):
    """The given lines of the file as an (n, width) matrix: each line's bytes cut at `width` and padded
    with blanks (the fixed-column layout the field decoder reads)."""
    out = np.full((rows.shape[0], width), _SPACE, np.uint8)
    for k in range(rows.shape[0]):
        a = starts[rows[k]]
        n = min(ends[rows[k]] - a, width)
        for j in range(n):
            out[k, j] = buf[a + j]
    return out
