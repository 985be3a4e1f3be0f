"""Figure furniture for the rendered pictures: fonts, colour maps, colour bars, scale bars.

Pillow only. Text is plain ASCII because the font that ships inside Pillow
(Aileron, ``ImageFont.load_default(size=...)``, Pillow >= 10.1) has no Greek or
math glyphs, and no system font can be assumed on a printer host.
"""

import functools
import math

import numpy as np
from PIL import Image, ImageDraw, ImageFont

# Colour maps as control points (position 0..1, R, G, B).
# "shrink": the paper's convention, blue = little shrink (thick layers) to red =
# much shrink (thin layers); hue falls monotonically from blue to red.
# "displacement": a sequential yellow-orange-red map whose lightness falls
# monotonically, so larger errors read darker even on a shaded surface.
# "height": hypsometric tint for height fields (low green to high pale stone).
COLORMAPS = {
    "shrink": np.array([
        [0.00, 45, 60, 185], [0.15, 30, 115, 225], [0.30, 35, 180, 215],
        [0.45, 75, 195, 125], [0.60, 180, 212, 60], [0.72, 248, 200, 42],
        [0.86, 240, 118, 32], [1.00, 195, 28, 24]]),
    "displacement": np.array([
        [0.00, 250, 244, 190], [0.25, 252, 205, 100], [0.50, 245, 140, 55],
        [0.75, 212, 60, 42], [1.00, 125, 14, 40]]),
    "height": np.array([
        [0.00, 92, 140, 98], [0.25, 150, 178, 112], [0.50, 210, 196, 138],
        [0.75, 182, 150, 112], [1.00, 242, 238, 232]]),
}
NAN_COLOR = (160, 160, 160)
INVALID_HIGH = (225, 0, 215)  # needs more shrink than the material gives
INVALID_LOW = (20, 20, 20)    # would need to expand
INVERTED = (25, 95, 235)     # settled the other way up (hatched on the preview)
INK = (35, 35, 40)
MUTED = (105, 105, 112)
WHITE = 255.0


def colormap(values, vmin, vmax, name="shrink"):
    """Map scalars to colours.

    Parameters
    ----------
    values : (k,) float
    vmin, vmax : float
        Values at the ends of the map; values outside are clipped to the ends.
    name : {"shrink", "displacement", "height"}

    Returns
    -------
    colors : (k, 3) uint8; NaN values get a neutral grey.
    """
    table = COLORMAPS[name]
    v = np.asarray(values, dtype=np.float64)
    span = vmax - vmin if vmax != vmin else 1.0
    t = np.clip((v - vmin) / span, 0.0, 1.0)
    out = np.empty(v.shape + (3,), dtype=np.float64)
    for k in range(3):
        out[..., k] = np.interp(t, table[:, 0], table[:, k + 1])
    out[np.isnan(v)] = NAN_COLOR
    return np.round(out).astype(np.uint8)


@functools.lru_cache(maxsize=16)
def font(size):
    """Pillow's bundled TrueType font at ``size`` px (bitmap fallback on old Pillow)."""
    try:
        return ImageFont.load_default(size=int(size))
    except TypeError:  # Pillow < 10.1 has no sized default font
        return ImageFont.load_default()


def text_size(text, fnt):
    """(width, height) in px of ``text`` set in ``fnt``."""
    box = fnt.getbbox(text)
    return box[2] - box[0], box[3] - box[1]


def nice_step(span, count=5):
    """A round step (1, 2, 2.5 or 5 times a power of ten) giving about ``count`` intervals."""
    if not span > 0:
        return 1.0
    raw = span / max(count, 1)
    p = 10.0 ** math.floor(math.log10(raw))
    for m in (1, 2, 2.5, 5, 10):
        if m * p >= raw * 0.999:
            return m * p
    return 10 * p


def nice_ceil(value):
    """Smallest round number (1, 2, 2.5, 5 times a power of ten) >= ``value``."""
    if not value > 0:
        return 1.0
    p = 10.0 ** math.floor(math.log10(value))
    for m in (1, 2, 2.5, 5, 10):
        if m * p >= value * (1 - 1e-9):
            return m * p
    return 10 * p


def counted(n, noun):
    """``n`` and ``noun``, plural unless one: "1 trace", "3 traces"."""
    return "%d %s%s" % (n, noun, "" if n == 1 else "s")


def fmt_number(v, step=None):
    """Compact number: decimals only as many as the step (or value) needs."""
    ref = abs(step) if step else abs(v)
    decimals = 0 if ref >= 1 or ref == 0 else min(4, int(math.ceil(-math.log10(ref) - 1e-9)))
    if step and decimals == 1 and round(step * 10) != step * 10:
        decimals = 2
    s = f"{v:.{decimals}f}"
    return "0" if s in ("-0", "-0.0", "-0.00") else s


def ticks(vmin, vmax, count=5):
    """Round tick values covering [vmin, vmax] and the step between them."""
    step = nice_step(vmax - vmin, count)
    start = math.ceil(vmin / step - 1e-9) * step
    vals = np.arange(start, vmax + step * 1e-6, step)
    return vals, step


def colorbar(img, x, y, w, h, cmap, vmin, vmax, label, scale=1.0, unit="", fs=14):
    """Vertical colour bar at (x, y) of size (w, h) px, vmax on top, with ticks.

    ``scale`` multiplies tick labels (e.g. 100 for per cent); returns the
    bounding box's right and bottom edges (px) for further layout.
    """
    draw = ImageDraw.Draw(img)
    fnt, small = font(fs), font(fs - 2)
    draw.text((x, y), label, font=fnt, fill=INK)
    y0 = y + text_size(label, fnt)[1] + int(fs * 0.9)
    t = np.linspace(vmax, vmin, h)
    bar = np.repeat(colormap(t, vmin, vmax, cmap)[:, None, :], w, axis=1)
    img.paste(Image.fromarray(bar), (x, y0))
    draw.rectangle([x - 1, y0 - 1, x + w, y0 + h], outline=INK)
    vals, step = ticks(vmin * scale, vmax * scale, 5)
    right = x + w
    for v in vals:
        frac = (v / scale - vmin) / (vmax - vmin) if vmax != vmin else 0.0
        ty = y0 + (1 - frac) * (h - 1)
        draw.line([x + w, ty, x + w + 5, ty], fill=INK)
        s = fmt_number(v, step) + unit
        tw, th = text_size(s, small)
        draw.text((x + w + 8, ty - th / 2 - 2), s, font=small, fill=INK)
        right = max(right, x + w + 8 + tw)
    return right, y0 + h


def scale_bar(img, x, y, px_per_mm, max_len_px, fs=14, color=INK):
    """Horizontal scale bar with a round length in mm; returns its right edge (px)."""
    limit = max_len_px / px_per_mm
    p = 10.0 ** math.floor(math.log10(limit))
    length = max(m * p for m in (1, 2, 5) if m * p <= limit * (1 + 1e-9))
    draw = ImageDraw.Draw(img)
    lp = length * px_per_mm
    hh = max(3, fs // 4)
    draw.rectangle([x, y, x + lp, y + hh], fill=color)
    draw.line([x, y - hh, x, y + 2 * hh], fill=color, width=2)
    draw.line([x + lp, y - hh, x + lp, y + 2 * hh], fill=color, width=2)
    s = f"{fmt_number(length)} mm"
    draw.text((x + lp + 8, y + hh / 2 - text_size(s, font(fs))[1] / 2 - 3), s, font=font(fs), fill=color)
    return x + lp + 8 + text_size(s, font(fs))[0]


def swatch(img, x, y, color, text, fs=14, shape="line"):
    """A legend entry: a short thick line (or a ring) in ``color`` then ``text``; returns the next y."""
    draw = ImageDraw.Draw(img)
    fnt = font(fs)
    th = max(text_size("Hg", fnt)[1], fs)
    cy = y + th / 2 + 2
    if shape == "ring":
        r = fs * 0.45
        draw.ellipse([x + 9 - r, cy - r, x + 9 + r, cy + r], outline=tuple(color), width=2)
    elif shape == "dot":
        r = fs * 0.35
        draw.ellipse([x + 9 - r, cy - r, x + 9 + r, cy + r], fill=tuple(color), outline=INK)
    elif shape == "dash":
        for k in range(3):
            draw.line([x + k * 7, cy, x + k * 7 + 4, cy], fill=tuple(color), width=2)
    else:
        draw.line([x, cy, x + 20, cy], fill=tuple(color), width=max(3, fs // 4))
    draw.text((x + 28, y), text, font=fnt, fill=INK)
    return y + int(th * 1.6)


def base_font_size(body_size):
    """Base font size (px) for a figure around a body of ``body_size`` (w, h)."""
    return int(np.clip(round(max(body_size) / 60), 14, 22))


def framed(body, title, subtitle="", legend_w=230, legend_min_h=420, footer_h=56, fs=None,
           legend_texts=()):
    """Place ``body`` (PIL image) in a white figure with a title band, legend column and footer.

    The legend column is at least ``legend_w`` wide and wide enough for each of
    ``legend_texts`` after a swatch. Returns (figure, body_xy, legend_xy,
    footer_xy, fs): where the body was pasted, where the legend column and the
    footer band start, and the base font size.
    """
    bw, bh = body.size
    fs = fs or base_font_size(body.size)
    need = [text_size(t, font(fs))[0] + 28 + fs for t in legend_texts]
    legend_w = max([legend_w] + need)
    title_h = int(fs * 1.6) + (int(fs * 1.3) if subtitle else 0) + fs
    pad = fs
    h = title_h + max(bh, legend_min_h) + footer_h
    w = max(pad + bw + pad + legend_w, text_size(title, font(int(fs * 1.3)))[0] + 2 * pad,
            text_size(subtitle, font(fs - 1))[0] + 2 * pad)
    fig = Image.new("RGB", (w, h), (255, 255, 255))
    draw = ImageDraw.Draw(fig)
    draw.text((pad, int(fs * 0.6)), title, font=font(int(fs * 1.3)), fill=INK)
    if subtitle:
        draw.text((pad, int(fs * 0.6) + int(fs * 1.6)), subtitle, font=font(fs - 1), fill=MUTED)
    by = title_h + (max(bh, legend_min_h) - bh) // 2
    fig.paste(body, (pad, by))
    return fig, (pad, by), (w - legend_w, title_h), (pad, title_h + max(bh, legend_min_h)), fs


def extent(points):
    """Per-column minimum and maximum of ``points`` (n, k): ((k,), (k,)).

    Column by column: numpy reduces a tall, narrow array along its first axis a row at a
    time (a 180 000 x 2 layout: 6 ms against 0.15)."""
    pts = np.asarray(points)
    return (np.array([pts[:, j].min() for j in range(pts.shape[1])]),
            np.array([pts[:, j].max() for j in range(pts.shape[1])]))


def to_image(canvas, band=64):
    """(h, w, 3) float canvas, 0-255 -> RGB ``PIL.Image``.

    Rounded and clipped ``band`` rows at a time: the temporaries of a whole canvas
    (24 MB as float32 for a 175 mm part) fall out of the cache between the passes.
    """
    out = np.empty(canvas.shape, np.uint8)
    for k in range(0, canvas.shape[0], band):
        q = np.rint(canvas[k:k + band])
        out[k:k + band] = np.clip(q, 0, 255, out=q)
    return Image.fromarray(out)


def stat_lines(img, x, y, lines, fs):
    """Muted text lines under a legend; returns the y below them."""
    draw = ImageDraw.Draw(img)
    for s in lines:
        draw.text((x, y), s, font=font(fs - 1), fill=MUTED)
        y += int(fs * 1.45)
    return y
