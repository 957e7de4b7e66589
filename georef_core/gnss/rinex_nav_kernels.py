"""Compiled (numba) reading of the numbers of RINEX navigation records: 19-character Fortran fields
(D or E exponent) in their fixed columns. rinex_nav.py groups the lines into records and hands over
those whose every field this reads exactly; the rest (free-format writers, numbers that need more than
a correctly rounded fast conversion, anything odd) take its Python path, which also words the errors.

The decimal mantissa (at most 15 significant digits) is an exact double; with a power of ten within
+-22 one multiplication or division rounds correctly and gives the same double as Python's float() and
C's strtod (Clinger's fast path). Other well-formed fields (1.705302565820D-12 is 1705302565820 x 1e-24)
are marked for Python's float(), so every value is bit-identical to RTKLIB's; anything malformed sends
the whole record back to the Python path.
"""

from __future__ import annotations

import numpy as np
from .kernel_loader import njit

_SPACE, _PLUS, _MINUS, _DOT, _ZERO, _NINE = 32, 43, 45, 46, 48, 57
_UPPER_D, _UPPER_E, _LOWER_D, _LOWER_E = 68, 69, 100, 101
FIELD_WIDTH = 19

_POW10 = np.array([10.0**k for k in range(23)])


@njit(cache=True)
def _field(buf, start, end, pow10):
    """(value, status) of buf[start:end] (one field, possibly cut short by the end of its line): status 0
    read, 1 a well-formed number the fast conversion cannot round exactly, 2 not a number."""
    i = start
    while i < end and buf[i] == _SPACE:
        i += 1
    if i == end:
        return 0.0, 0          # blank field
    neg = False
    if buf[i] == _MINUS or buf[i] == _PLUS:
        neg = buf[i] == _MINUS
        i += 1
    mant = 0
    hard = False
    n_sig = 0
    n_digits = 0
    scale = 0                  # decimal digits after the point
    seen_dot = False
    while i < end:
        ch = buf[i]
        if _ZERO <= ch <= _NINE:
            n_digits += 1
            if mant > 0 or ch != _ZERO:
                n_sig += 1
                if n_sig > 15:
                    hard = True
            mant = mant * 10 + (ch - _ZERO)
            if seen_dot:
                scale += 1
        elif ch == _DOT and not seen_dot:
            seen_dot = True
        else:
            break
        i += 1
    if n_digits == 0:
        return 0.0, 2
    exp = 0
    if i < end and (buf[i] == _UPPER_D or buf[i] == _UPPER_E or buf[i] == _LOWER_D or buf[i] == _LOWER_E):
        i += 1
        exp_neg = False
        if i < end and (buf[i] == _MINUS or buf[i] == _PLUS):
            exp_neg = buf[i] == _MINUS
            i += 1
        n_exp = 0
        while i < end and _ZERO <= buf[i] <= _NINE:
            exp = exp * 10 + (buf[i] - _ZERO)
            n_exp += 1
            i += 1
            if n_exp > 3:
                return 0.0, 2
        if n_exp == 0:
            return 0.0, 2
        if exp_neg:
            exp = -exp
    while i < end and buf[i] == _SPACE:
        i += 1
    if i != end:
        return 0.0, 2          # text after the number inside the field
    if hard:
        return 0.0, 1
    p10 = exp - scale
    value = float(mant)
    if mant != 0:
        if p10 > 22 or p10 < -22:
            return 0.0, 1
        if p10 >= 0:
            value = value * pow10[p10]
        else:
            value = value / pow10[-p10]
    return (-value if neg else value), 0


@njit(cache=True)
def record_fields(buf, line_start, line_len, rec_line, rec_n_lines, data_col, cont_col, n_values):
    """Numbers of each record (rows of (n_records, n_values), zero-padded): 3 fields from column data_col of
    its first line, 4 from column cont_col of each further line. ok[r] is False when a field of record r
    is not a number or a line carries text beyond its fields; hard (n_hard, 4: record, value index, first
    and end byte offset of the field) lists the fields left to Python's float()."""
    n_rec = rec_line.shape[0]
    values = np.zeros((n_rec, n_values))
    ok = np.ones(n_rec, np.bool_)
    hard = np.empty((n_rec * n_values, 4), np.int64)
    n_hard = 0
    pow10 = _POW10
    for r in range(n_rec):
        k = 0
        first_hard = n_hard
        for m in range(rec_n_lines[r]):
            ln = rec_line[r] + m
            s0 = line_start[ln]
            length = line_len[ln]
            col = data_col if m == 0 else cont_col
            count = 3 if m == 0 else 4
            for f in range(count):
                a = col + f * FIELD_WIDTH
                b = a + FIELD_WIDTH
                if k >= n_values:
                    ok[r] = False
                    break
                if a < length:
                    v, status = _field(buf, s0 + a, s0 + min(b, length), pow10)
                    if status == 2:
                        ok[r] = False
                        break
                    if status == 1:
                        hard[n_hard, 0] = r
                        hard[n_hard, 1] = k
                        hard[n_hard, 2] = s0 + a
                        hard[n_hard, 3] = s0 + min(b, length)
                        n_hard += 1
                    values[r, k] = v
                k += 1
            if not ok[r]:
                break
            tail = col + count * FIELD_WIDTH
            for q in range(tail, length):
                if buf[s0 + q] != _SPACE:
                    ok[r] = False
                    break
            if not ok[r]:
                break
        if not ok[r]:
            n_hard = first_hard   # the record goes to the Python path whole
    return values, ok, hard[:n_hard]


@njit(cache=True)
def record_epoch_fields(buf, line_start, line_len, rec_line, cols):
    """Integer calendar fields (n_records, 6) of each record's first line, read at the (first column,
    width) pairs `cols` (year, month, day, hour, minute, second), and whether each record's were readable:
    every field digits after leading blanks only, at least one digit, the line long enough."""
    n_rec = rec_line.shape[0]
    n_f = cols.shape[0]
    fields = np.zeros((n_rec, n_f), np.int64)
    readable = np.ones(n_rec, np.bool_)
    last = cols[n_f - 1, 0] + cols[n_f - 1, 1]
    for r in range(n_rec):
        s0 = line_start[rec_line[r]]
        if line_len[rec_line[r]] < last:
            readable[r] = False
            continue
        for f in range(n_f):
            value = 0
            seen_digit = False
            for k in range(cols[f, 1]):
                ch = buf[s0 + cols[f, 0] + k]
                if _ZERO <= ch <= _NINE:
                    value = value * 10 + (ch - _ZERO)
                    seen_digit = True
                elif ch != _SPACE or seen_digit:
                    readable[r] = False
            if not seen_digit:
                readable[r] = False
            fields[r, f] = value
    return fields, readable


def fill_hard_fields(values: np.ndarray, buf: np.ndarray, hard: np.ndarray) -> None:
    """Python's float() (correctly rounded, as strtod) for the fields record_fields left to it."""
    if len(hard) == 0:
        return
    raw = buf.tobytes()
    texts = [raw[a:b].replace(b"D", b"E").replace(b"d", b"e") for a, b in hard[:, 2:].tolist()]
    values[hard[:, 0], hard[:, 1]] = [float(t) for t in texts]
