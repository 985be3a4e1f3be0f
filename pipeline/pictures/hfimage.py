"""The picture of an input: its height field hillshaded, with isolines and the peaks
that simplification removed (``NAME.input.png``).

numpy + Pillow (+ contourpy for the isolines); top view with +y (north) up and the
mm-to-pixel map in ``image.info`` like :mod:`pipeline.pictures.render`'s pictures.
"""

import numpy as np
from PIL import Image

from pipeline.pictures.figure import (WHITE, colorbar, colormap, fmt_number, framed, nice_ceil, scale_bar,
                             stat_lines, swatch, to_image)
from pipeline.pictures.raster import draw_segments

PEAK_COLOR = (215, 25, 35)


def _fill_nearest(z):
    from scipy import ndimage

    bad = ~np.isfinite(z)
    if not bad.any():
        return z
    idx = ndimage.distance_transform_edt(bad, return_distances=False, return_indices=True)
    return z[tuple(idx)]


def _hillshade(gy, gx, azimuth_deg=315.0, altitude_deg=45.0):
    """Lambertian hillshade (0..1) of a grid in mm from its gradient (``np.gradient``: rows
    run south, so -gy is the northward slope); light from the north-west by default."""
    nx, ny, nz = -gx, gy, np.ones_like(gx)
    norm = np.sqrt(nx * nx + ny * ny + 1.0)
    az, alt = np.radians(azimuth_deg), np.radians(altitude_deg)
    lx, ly, lz = np.cos(alt) * np.sin(az), np.cos(alt) * np.cos(az), np.sin(alt)
    return np.clip((nx * lx + ny * ly + nz * lz) / norm, 0.0, 1.0)


def _shaded_relief(zb, pixel_mm, zmin, zmax, a, big, band=64):
    """The tinted, hillshaded relief (H, W, 3) on white outside the footprint.

    zb : (H, W) heights; a : (H, W) footprint coverage; big : (H, W) share where the fit
    moved the surface (tinted), or None. Worked out ``band`` rows and one colour channel at
    a time: the dozen whole-picture float64 temporaries fell out of the cache between the
    passes, and a per-pixel factor broadcast over the channels makes numpy loop three
    values at a time. float32 as the rasteriser prefers, float64 when tinted (as it was).
    """
    gy, gx = np.gradient(zb, pixel_mm)
    H, W = zb.shape
    canvas = np.empty((H, W, 3), np.float32 if big is None else np.float64)
    tint = np.array(REMOVED_COLOR) * 0.35
    for r in range(0, H, band):
        s = slice(r, r + band)
        lit = 0.45 + 0.65 * _hillshade(gy[s], gx[s])
        cmap = colormap(zb[s], zmin, zmax, "height")
        white = WHITE * (1 - a[s])
        if big is not None:
            keep = 1 - 0.35 * big[s] * a[s]
        for k in range(3):
            c = (np.clip(cmap[..., k] * lit, 0, 255) * a[s] + white).astype(np.float32)
            canvas[s, :, k] = c if big is None else c * keep + tint[k] * big[s] * a[s]
    return canvas


REMOVED_COLOR = (150, 40, 160)


def heightfield_image(z, removed_peaks=(), pixel_mm=1.0, title="", isoline_step_mm=None,
                      long_px=900, removed_count=None, removed_mm=None, removed_at_mm=0.25):
    """Hillshaded height field with isolines and the peaks that simplification removed.

    Parameters
    ----------
    z : (rows, cols) float, mm
        Heights, NaN outside the footprint; row 0 is north.
    removed_peaks : iterable of dict with ``x_mm``, ``y_mm``, ``prominence_mm``
        Positions as in :class:`pipeline.geometry.HeightField` (x = col * pixel_mm,
        y = (rows - 1 - row) * pixel_mm); drawn as red rings sized by prominence.
    pixel_mm : float
    title : str
    isoline_step_mm : float, optional
        Isoline spacing; default a round step giving ~12 lines. Every fifth is bold.
    long_px : int
        Longest side of the picture.
    removed_count : int, optional
        How many peaks were removed in all, when ``removed_peaks`` lists only the
        most prominent ones.
    removed_mm : (rows, cols) float, mm, optional
        What the fit removed per sample: the places it moved by more than
        ``removed_at_mm`` are tinted and outlined.

    Returns
    -------
    PIL.Image with ``info["px_per_mm"]`` and ``info["origin_px"]``.
    """
    import contourpy

    z = np.asarray(z, dtype=np.float64)
    rows, cols = z.shape
    valid = np.isfinite(z)
    zf = np.nan_to_num(_fill_nearest(z), nan=0.0)
    zmax = float(np.nanmax(z)) if valid.any() else 1.0
    zmin = float(np.nanmin(z)) if valid.any() else 0.0
    f = long_px / max(rows, cols)  # display px per grid sample
    W, H = int(round(cols * f)), int(round(rows * f))
    # Shade the bicubically resampled heights, not the samples: shading coarse
    # samples and enlarging the result shows every sample as a facet.
    zb = np.asarray(Image.fromarray(zf.astype(np.float32), "F").resize((W, H), Image.BICUBIC),
                    np.float64)
    # The footprint's edge is the 0.5 level of the bilinearly enlarged mask, with a
    # 1 px ramp: smooth diagonals instead of sample-sized stair steps.
    mask = Image.fromarray(valid.astype(np.float32), "F").resize((W, H), Image.BILINEAR)
    a = np.clip((np.asarray(mask, np.float64) - 0.5) * f + 0.5, 0.0, 1.0)
    moved = big = None
    if removed_mm is not None:
        moved = np.nan_to_num(np.asarray(removed_mm, np.float64), nan=0.0)
        big = np.asarray(Image.fromarray((moved > removed_at_mm).astype(np.float32), "F")
                         .resize((W, H), Image.BILINEAR), np.float64)
    canvas = _shaded_relief(zb, pixel_mm * cols / W, zmin, zmax, a, big)

    step = isoline_step_mm or nice_ceil((zmax - zmin) / 12)
    levels = np.arange(np.ceil(zmin / step) * step + (step if zmin % step == 0 else 0), zmax, step)
    if len(levels):
        gen = contourpy.contour_generator(z=np.ma.masked_invalid(z), line_type="SeparateCode")
        q0, q1, width = [], [], []
        for lev in levels:
            segs = [line for line in gen.lines(lev)[0] if len(line) > 1]
            bold = abs(lev / step / 5 - round(lev / step / 5)) < 1e-6
            q0 += [s[:-1] for s in segs]
            q1 += [s[1:] for s in segs]
            width += [np.full(len(s) - 1, 1.5 if bold else 0.8) for s in segs]
        if q0:  # all levels in one call: each call costs a pass over the whole canvas
            draw_segments(canvas, (np.concatenate(q0) + 0.5) * f, (np.concatenate(q1) + 0.5) * f,
                          (70, 52, 40), np.concatenate(width))
    if moved is not None and (moved > removed_at_mm).any():
        gen = contourpy.contour_generator(z=moved, line_type="SeparateCode")
        segs = [line for line in gen.lines(removed_at_mm)[0] if len(line) > 1]
        if segs:
            q0 = np.concatenate([s_[:-1] for s_ in segs])
            q1 = np.concatenate([s_[1:] for s_ in segs])
            draw_segments(canvas, (q0 + 0.5) * f, (q1 + 0.5) * f, REMOVED_COLOR, 2.0)
    peaks = list(removed_peaks)
    if peaks:
        c = np.array([[p["x_mm"] / pixel_mm, rows - 1 - p["y_mm"] / pixel_mm] for p in peaks])
        prom = np.array([float(p.get("prominence_mm", 0.0)) for p in peaks])
        r = 6.0 + 4.0 * np.sqrt(np.maximum(prom, 0))
        ang = np.linspace(0, 2 * np.pi, 33)
        ring = (c[:, None, :] + 0.5) * f + r[:, None, None] * np.stack([np.cos(ang), np.sin(ang)], -1)
        draw_segments(canvas, ring[:, :-1].reshape(-1, 2), ring[:, 1:].reshape(-1, 2),
                      PEAK_COLOR, 2.5)
    plan_s = f / pixel_mm
    sub = (f"{cols * pixel_mm:.0f} x {rows * pixel_mm:.0f} mm  |  height {zmin:.1f}-{zmax:.1f} mm  |  "
           f"{cols} x {rows} samples at {fmt_number(pixel_mm, 0.01)} mm")
    fig, bxy, (lx, ly), (fx, fy), fs = framed(to_image(canvas), title or "height field", sub,
                                              legend_w=250, legend_min_h=360)
    _, yb = colorbar(fig, lx, ly, 26, min(300, max(180, H // 2)), "height", zmin, zmax,
                     "height (mm)", fs=fs)
    y = swatch(fig, lx, yb + fs, (70, 52, 40), f"isolines every {fmt_number(step)} mm", fs)
    if moved is not None and (moved > removed_at_mm).any():
        share = float((moved > removed_at_mm).sum() / max(valid.sum(), 1))
        y = swatch(fig, lx, y, REMOVED_COLOR, f"fit moved > {fmt_number(removed_at_mm)} mm", fs)
        y = stat_lines(fig, lx, y, [f"on {100 * share:.0f} % (max {np.nanmax(moved):.1f} mm)"],
                       fs)
    total = max(int(removed_count or 0), len(peaks))
    if total:
        shown = "" if total == len(peaks) else f" ({len(peaks)} shown)"
        y = swatch(fig, lx, y, PEAK_COLOR, f"{total} peaks simplified{shown}", fs, shape="ring")
        lines = [f"prominence <= {prom.max():.1f} mm"] if peaks else []
        stat_lines(fig, lx, y, lines + ["(not reproduced)"], fs)
    scale_bar(fig, bxy[0], fy + fs, plan_s, min(0.4 * W, 300), fs)
    fig.info["px_per_mm"] = plan_s
    fig.info["origin_px"] = (bxy[0] + 0.5 * f, bxy[1] + (rows - 0.5) * f)
    return fig
