"""Print-time estimate for G-code moves: a trapezoid per move.

Each move accelerates at ``accel`` (mm/s^2) from its entry speed to the feed
rate, cruises, and decelerates to its exit speed. Junction speeds inside a
continuous trace come from Marlin's junction deviation (gentle turns keep
the speed, a 90 degree corner drops to a few mm/s, a reversal stops); traces
start and end at rest. Reachability is applied once per move (entry/exit
speeds limited by what the move's length allows), not through Marlin's full
look-ahead passes, so long runs of very short moves with sharp turns are
estimated slightly optimistically. Vectorised over all moves.
"""

import numpy as np

ACCELERATION_MM_S2 = 1000.0
JUNCTION_DEVIATION_MM = 0.013
MAX_Z_SPEED_MM_S = 10.0


def trapezoid_s(length, v0, v1, vmax, accel):
    """Time (s) of moves of ``length`` (mm) entered at ``v0``, left at ``v1`` (mm/s).

    ``length``, ``v0``, ``v1`` broadcast; ``vmax`` is the feed rate.
    """
    length = np.asarray(length, dtype=float)
    v0 = np.minimum(v0, vmax)
    v1 = np.minimum(v1, vmax)
    v1 = np.minimum(v1, np.sqrt(v0 * v0 + 2 * accel * length))
    v0 = np.minimum(v0, np.sqrt(v1 * v1 + 2 * accel * length))
    d_acc = (vmax * vmax - v0 * v0) / (2 * accel)
    d_dec = (vmax * vmax - v1 * v1) / (2 * accel)
    cruise = d_acc + d_dec <= length
    vp = np.sqrt(np.maximum((2 * accel * length + v0 * v0 + v1 * v1) / 2.0, 0.0))
    vp = np.where(cruise, vmax, vp)
    t = (vp - v0) / accel + (vp - v1) / accel
    return t + np.where(cruise, (length - d_acc - d_dec) / vmax, 0.0)


def polyline_time_s(points_mm, starts, speed, accel=ACCELERATION_MM_S2,
                    junction_deviation_mm=JUNCTION_DEVIATION_MM):
    """Time to run a set of polylines at ``speed`` mm/s.

    Parameters
    ----------
    points_mm : (n, 2) float, mm
        All traces' points, concatenated.
    starts : (t + 1,) int
        Trace i owns ``points_mm[starts[i]:starts[i + 1]]`` (at least 2 points).
    speed : float, or (s,) float per segment (the traces' segments in order), mm/s

    Returns
    -------
    (time_s, length_mm) : float, float
    """
    seg_mask = np.ones(len(points_mm), bool)
    seg_mask[starts[:-1]] = False
    d = np.diff(points_mm, axis=0)[seg_mask[1:]]
    length = np.hypot(d[:, 0], d[:, 1])
    u = d / np.maximum(length, 1e-12)[:, None]
    # Marlin: v_junction^2 = a * jd * sin(theta/2) / (1 - sin(theta/2)).
    cos_j = -np.einsum("ij,ij->i", u[:-1], u[1:])
    sin_half = np.sqrt(np.clip(0.5 * (1.0 - cos_j), 0.0, 1.0))
    with np.errstate(divide="ignore"):
        vj = np.sqrt(accel * junction_deviation_mm * sin_half / np.maximum(1 - sin_half, 0))
    speed = np.broadcast_to(np.asarray(speed, float), length.shape)
    # A junction is taken no faster than either move's feed rate.
    v = np.concatenate([[0.0], np.minimum(vj, np.minimum(speed[:-1], speed[1:])), [0.0]])
    seg_first = starts[:-1] - np.arange(len(starts) - 1)
    v_in = v[:-1].copy()
    v_out = v[1:].copy()
    v_in[seg_first] = 0.0
    v_out[seg_first[1:] - 1] = 0.0
    return float(trapezoid_s(length, v_in, v_out, speed, accel).sum()), float(length.sum())


def estimate_time_text(seconds):
    """PrusaSlicer's time format: ``1d 2h 3m 4s``, leading zero units dropped."""
    s = int(round(seconds))
    parts = []
    for unit, n in (("d", 86400), ("h", 3600), ("m", 60)):
        if s >= n or parts:
            parts.append("%d%s" % (s // n, unit))
            s %= n
    parts.append("%ds" % s)
    return " ".join(parts)
