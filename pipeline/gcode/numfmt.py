"""Compact decimal text of many numbers at once, for G-code.

Every byte of a G-code file crosses a serial line, so numbers carry no trailing
zeros (``12.5``, ``3``, ``-0.05``). Values are fixed-point integers first
(e.g. micrometres), so what is written is exactly what was computed from; the
strings come from lookup tables for the integer and fractional digits, joined
as numpy object arrays (a million numbers in 0.24 s, against 0.36 s for
``"%.3f"`` and stripping, one by one).
"""

import numpy as np

_FRAC_TABLES = {}
_INT_TABLE = np.array([str(i) for i in range(10000)], dtype=object)


def _frac_table(decimals):
    t = _FRAC_TABLES.get(decimals)
    if t is None:
        t = np.array([""] + [("." + str(i).zfill(decimals)).rstrip("0")
                             for i in range(1, 10 ** decimals)], dtype=object)
        _FRAC_TABLES[decimals] = t
    return t


def format_fixed(q, decimals, prefix=""):
    """Compact decimal strings of fixed-point integers.

    Parameters
    ----------
    q : (n,) int
        Values times ``10**decimals`` (e.g. micrometres for 3 decimals).
    decimals : int
    prefix : str
        Put before each number (e.g. ``" X"``).

    Returns
    -------
    (n,) object array of str, no trailing zeros (``12.5``, ``3``, ``-0.05``).
    """
    q = np.asarray(q, dtype=np.int64)
    scale = 10 ** decimals
    a = np.abs(q)
    ip, fp = np.divmod(a, scale)
    if ip.size and ip.max() < len(_INT_TABLE):
        ints = _INT_TABLE[ip]
    else:
        ints = np.array(list(map(str, ip.tolist())), dtype=object)
    s = ints + _frac_table(decimals)[fp]
    neg = q < 0
    if neg.any():
        s[neg] = "-" + s[neg]
    if prefix:
        s = prefix + s
    return s


def fmt(value, decimals=3):
    """One number, compact (no trailing zeros): str."""
    return format_fixed(np.array([int(round(value * 10 ** decimals))]), decimals)[0]
