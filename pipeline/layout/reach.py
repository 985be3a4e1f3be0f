"""How much of the target's curvature the printed sheet can program.

Shrink differences through the stack curl the sheet; the most any stack of thickness
``h`` can give is a bilayer of the whole shrink range, ``c * (s_max - s_min) / h``
(about 0.3 /mm, a radius of 3 mm, for 34 % over 1.6 mm). A target that bends faster
than that, over more than a sliver of the sheet, does not form whatever the layout:
the sheet settles into a smoother shape and misses the target by the difference.

Measured on the free method's plans (mean displacement over the diameter), ``reach`` the
90th percentile of the target's largest principal curvature over that limit:

| input | reach p90 | displacement |
|---|---|---|
| reference shapes (dome, starfish, saddles, islands, terrain tile) | 0.03-0.20 | 0.03-0.29 % |
| coast tile fitted to the metric (relief 0.29) | 1.42 | 5.3 % |
| Vancouver tile fitted to the metric (relief 0.34) | 0.83 | 3.9 % |
| Vancouver, full relief, smoothed 4 / 5 / 6 mm | 0.48 / 0.39 / 0.31 | 1.40 / 0.85 / 0.60 % |
| coast, full relief, smoothed 4 / 6 mm | 0.84 / 0.50 | 2.9 / 0.95 % |

With the full target curvature as the sheet's rest curvature the coast tile at relief
0.29 lands within 1.6 %; clipped to the stack's limit it lands 5.9 % off, as the plan
does: the misses of the real tiles are this limit, not the program. Lowering the relief
lowers the curvature only in proportion; smoothing removes the narrow ridges that need
it, so the fit smooths first (:mod:`pipeline.layout.fit`).
"""

import numpy as np

from pipeline.geometry import signed_areas_2d

# The share of the limit the 90th percentile may use: at 0.39 the Vancouver tile
# formed within 0.85 %, at 0.48 it missed by 1.4 %.
WITHIN = 0.4


def curvature_limit(thickness_mm, s_min, s_max, c):
    """The largest curvature (1/mm) a stack of ``thickness_mm`` ((m,)) can program: a
    bilayer of the whole shrink range. (m,)."""
    return c * (s_max - s_min) / np.asarray(thickness_mm, dtype=float)


def reach_ratio(K, thickness_mm, s_min, s_max, c):
    """Per triangle, the target's largest principal curvature over the stack's limit.

    K : (m, 2, 2) 1/mm, the target's curvature (:func:`pipeline.layout.curvature.
    target_tensor`); thickness_mm : (m,) the printed stack. Returns (m,), above 1 where
    no stack of that thickness can bend as far."""
    K = np.asarray(K, dtype=float)
    k = np.abs(np.linalg.eigvalsh(0.5 * (K + K.transpose(0, 2, 1)))).max(axis=1)
    return k / curvature_limit(thickness_mm, s_min, s_max, c)


def reach(hf, mesh, flat, profile, smooth_mm=None):
    """The report's ``reach`` of a free layout ``flat`` of ``mesh`` over ``hf``: the
    target's curvature (smoothed ``smooth_mm``, default the plan's grid spacing: what
    the sheet's mesh can hold) against the stack's limit, ``{"p50", "p90", "max",
    "beyond_fraction" (share of the sheet's area above the limit), "within" (p90 at most
    :data:`WITHIN`)}``."""
    from pipeline.layout import curvature
    from pipeline.simulation.shell import thickness_for
    lim = profile.shrink_limits
    sigma = np.clip(flat.sigma, lim.s_min, lim.s_max)
    h = thickness_for(sigma, profile.shrink_curve, profile.layers, profile.thickness_mm.min,
                      profile.thickness_mm.max)
    K = curvature.target_tensor(hf, mesh, flat, sigma,
                                smooth_mm=profile.mesh.grid_mm if smooth_mm is None else smooth_mm)
    ratio = reach_ratio(K, h, lim.s_min, lim.s_max, profile.curvature.bilayer_c)
    area = np.abs(signed_areas_2d(np.asarray(flat.xy, dtype=float), mesh.faces))
    p50, p90 = (float(v) for v in np.percentile(ratio, [50, 90]))
    return {"p50": round(p50, 4), "p90": round(p90, 4), "max": round(float(ratio.max()), 4),
            "beyond_fraction": round(float(area[ratio > 1].sum() / max(area.sum(), 1e-12)), 4),
            "within": bool(p90 <= WITHIN)}
