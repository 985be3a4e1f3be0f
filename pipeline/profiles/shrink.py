"""Layer thickness <-> shrink ratio, from a printer's measured curve (paper Fig. 2).

``sigma`` is the shrink ratio ``1 - target_length / flat_length`` (0..1);
``theta`` is the layer thickness in mm. Thinner layers are stretched more when
extruded and shrink more, so over the usable range sigma decreases with theta.
"""

import numpy as np

from pipeline.errors import InvalidProfile

# Samples used to check monotonicity and to invert the fitted polynomial.
_SAMPLES = 2001


class ShrinkCurve:
    """Polynomial fit sigma(theta) over an allowed thickness range.

    Parameters
    ----------
    thickness_mm : (k,) float
        Measured layer thicknesses.
    shrink : (k,) float
        Measured shrink ratios (0..1) at those thicknesses.
    degree : int
        Polynomial degree (the paper uses 4).
    theta_range_mm : (2,) float
        Allowed thickness range; the fit must be strictly monotonic on it.
    source : str, optional
        File the numbers came from, for error messages.
    """

    def __init__(self, thickness_mm, shrink, degree=4, theta_range_mm=None, source=None):
        t = np.asarray(thickness_mm, dtype=float)
        s = np.asarray(shrink, dtype=float)
        where = "shrink_curve"
        if t.ndim != 1 or t.shape != s.shape:
            raise InvalidProfile("shrink curve thickness and shrink lists differ in length",
                                 code="profile.shrink_curve_shape", file=source, where=where,
                                 fix="give one shrink value per thickness value")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(s))):
            raise InvalidProfile("shrink curve has non-numeric or infinite values",
                                 code="profile.shrink_curve_values", file=source, where=where,
                                 fix="use plain numbers")
        if np.any(t <= 0) or np.any(s < 0) or np.any(s >= 1):
            raise InvalidProfile("shrink curve needs thickness > 0 mm and 0 <= shrink < 1",
                                 code="profile.shrink_curve_values", file=source, where=where,
                                 fix="shrink is a fraction (0.343 means 34.3 %)")
        degree = int(degree)
        if degree < 1 or len(np.unique(t)) <= degree:
            raise InvalidProfile(
                "shrink curve has %d distinct thicknesses, too few for a degree-%d fit"
                % (len(np.unique(t)), degree), code="profile.shrink_curve_too_few",
                file=source, where=where,
                fix="measure more thickness values or lower shrink_curve.degree")
        if theta_range_mm is None:
            theta_range_mm = (t.min(), t.max())
        lo, hi = float(theta_range_mm[0]), float(theta_range_mm[1])
        if not lo < hi:
            raise InvalidProfile("allowed thickness range is empty (%g..%g mm)" % (lo, hi),
                                 code="profile.thickness_range", file=source,
                                 where="thickness_mm", fix="set min below max")
        self.degree = degree
        self.theta_range_mm = (lo, hi)
        self.thickness_mm = t
        self.shrink = s
        self.coef = np.polyfit(t, s, degree)
        self.residuals = s - np.polyval(self.coef, t)
        grid = np.linspace(lo, hi, _SAMPLES)
        sig = np.polyval(self.coef, grid)
        d = np.diff(sig)
        if not (np.all(d < 0) or np.all(d > 0)):
            bad = grid[1:][np.sign(d) != np.sign(d[0])][0] if np.any(d != 0) else lo
            raise InvalidProfile(
                "the fitted shrink curve is not monotonic over the allowed thickness range "
                "%.3g..%.3g mm (it turns near %.3g mm), so a shrink ratio would map to two "
                "thicknesses" % (lo, hi, bad), code="profile.shrink_not_monotonic",
                file=source, where="shrink_curve",
                fix="narrow thickness_mm.min/max to where shrink changes one way, "
                    "lower the degree, or re-measure")
        if np.any(sig < -1e-9) or np.any(sig >= 1):
            raise InvalidProfile(
                "the fitted shrink curve leaves 0..1 on the allowed thickness range",
                code="profile.shrink_curve_values", file=source, where="shrink_curve",
                fix="narrow thickness_mm.min/max to the measured range")
        order = np.argsort(sig)
        self._sig_sorted = sig[order]
        self._theta_sorted = grid[order]
        self.sigma_range = (float(sig.min()), float(sig.max()))

    def sigma(self, theta_mm):
        """Shrink ratio at layer thickness ``theta_mm`` (array-like, mm)."""
        return np.polyval(self.coef, np.asarray(theta_mm, dtype=float))

    def theta(self, sigma):
        """Layer thickness (mm) for shrink ratio ``sigma`` (array-like).

        Returns ``(theta_mm, clamped)`` where ``clamped`` marks values whose
        sigma was outside the curve's range and got the nearest limit.
        """
        s = np.asarray(sigma, dtype=float)
        lo, hi = self.sigma_range
        clamped = (s < lo) | (s > hi) | ~np.isfinite(s)
        sc = np.clip(np.nan_to_num(s, nan=lo), lo, hi)
        return np.interp(sc, self._sig_sorted, self._theta_sorted), clamped
