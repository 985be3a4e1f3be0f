"""What it would take to form the input as given: a larger sheet, or a thinner stack.

Two limits make the fit smooth or lower a relief (:mod:`pipeline.layout.fit`): slopes
steeper than the shrink range forms, and curvature beyond what the stack can curl
(:mod:`pipeline.layout.reach`). Scaled as a whole (footprint and relief together) a
shape keeps its slopes and its curvature falls as one over the size, so the curvature
limit moves with the size and the slope limit does not. The stack's limit is
``c * (s_max - s_min) / h``: fewer layers of the same thickness curl tighter in
proportion. From the reach of the input as given (its 90th percentile over the limit,
``p90``, which forms within :data:`pipeline.layout.reach.WITHIN`):

- ``size_mm_as_given``: the size at which the curvature is within reach,
  ``size * p90 / WITHIN`` (None when the slopes do not form at any size);
- ``layers_as_given``: the most layers whose stack reaches it, ``floor(layers * WITHIN /
  p90)`` (None when even one layer does not), with the reach of the thinnest stack.
"""

import math

from pipeline.layout.reach import WITHIN
from pipeline.layout.fit import TARGET


def keep(reach_p90, slopes_form, size_mm, layers):
    """The report's ``keep`` section.

    reach_p90 : the input's curvature reach as given (90th percentile over the stack's
    limit); slopes_form : its layout as given leaves at most the fit's target outside
    the shrink range, without folds; size_mm : its longest footprint side now; layers :
    the profile's stack."""
    factor = max(reach_p90 / WITHIN, 1.0)
    most = int(math.floor(layers * WITHIN / reach_p90 + 1e-9)) if reach_p90 > 0 else layers
    fewest = min(max(1, most), layers)
    fits = reach_p90 * fewest / layers <= WITHIN * (1 + 1e-9)
    return {"reach_p90": round(reach_p90, 4), "slopes_form": bool(slopes_form),
            "size_mm": round(size_mm, 1),
            "size_mm_as_given": round(size_mm * factor, 1) if slopes_form else None,
            "size_factor": round(factor, 3), "layers": int(layers),
            "layers_as_given": fewest if fits else None,
            "reach_p90_one_layer": round(reach_p90 / layers, 4)}


def of_fit(fit, size_mm, layers):
    """``keep`` from a :class:`pipeline.layout.fit.Fit` that looked at the input as given
    (None where it did not)."""
    if fit is None or not fit.reach_given or not fit.tried:
        return None
    scale, invalid, flipped = fit.tried[0]
    if scale != 1.0:
        return None
    return keep(fit.reach_given["p90"], invalid <= TARGET and flipped == 0, size_mm, layers)


def sentence(k):
    """The warning's sentence on what would form the input as given, or '' where it
    forms already."""
    if k is None or (k["slopes_form"] and k["size_factor"] <= 1.0):
        return ""
    parts = []
    if k["slopes_form"]:
        parts.append("at `size_mm: %.0f` (now %.0f mm) its ridges and valleys bend within "
                     "the sheet's reach" % (math.ceil(k["size_mm_as_given"]), k["size_mm"]))
        if k["layers_as_given"] is not None and k["layers_as_given"] < k["layers"]:
            parts.append("a thinner stack of %d layers instead of %d (`layers: %d` in a copy "
                         "of the profile) curls tight enough at this size"
                         % (k["layers_as_given"], k["layers"], k["layers_as_given"]))
        elif k["layers"] > 1:
            parts.append("no thinner stack of this profile reaches it at this size (one "
                         "layer would still need %.1f times its reach)"
                         % (k["reach_p90_one_layer"] / WITHIN))
    else:
        parts.append("its slopes are steeper than the shrink range forms at any size: only "
                     "a lower or smoother relief forms them")
    return "to form the file as given: " + "; ".join(parts)
