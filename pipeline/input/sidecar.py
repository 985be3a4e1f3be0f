"""The sidecar ``NAME.yaml`` beside an input: physical scale and per-file options.

Errors (``InvalidSidecar``): ``sidecar.yaml``, ``.unknown_key``, ``.type``, ``.value``,
``.conflict``, ``.profile``, ``.too_large`` (over :data:`MAX_SIDECAR_BYTES`, refused
unparsed), ``.unreadable``; each names the file, the key and the fix.
"""

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import yaml

from pipeline.errors import InvalidSidecar
from pipeline.profiles.profile import MeshParams, ValidateParams


@dataclass(frozen=True)
class Sidecar:
    """Options from ``NAME.yaml`` beside an input (all optional).

    size_mm : longest footprint side, mm (or ``pixel_mm``: grid spacing, mm)
    height_mm : maximum height, mm (or ``height_scale``: mm per input unit)
    profile : name of the profile to plan with (a name only, never a path)
    max_fill_mm : deepest closed depression to fill, mm (overrides the profile)
    min_prominence_mm : smallest peak kept by simplification, mm (overrides the profile)
    smooth_mm : smoothing scale before meshing, mm (overrides the profile)
    copies : how many sheets to print (>= 1); priority : queue priority (daemon)
    fit : ``auto``, ``relief`` or ``off``: make the relief form (free layout method):
    smoothed where that forms it at full height, else lowered (``auto``); only lowered
    (``relief``); as given (``off``)
    method : ``isoline`` or ``free``: the layout method (overrides the profile's)
    up : for a mesh, the axis that points up: ``x``, ``y``, ``z``, ``-x``, ``-y`` or ``-z``
    (default: the one along which its surface is a height field)
    source : the sidecar file, or None when there is none
    """

    size_mm: float = None
    pixel_mm: float = None
    height_mm: float = None
    height_scale: float = None
    profile: str = None
    max_fill_mm: float = None
    min_prominence_mm: float = None
    smooth_mm: float = None
    fit: str = None
    method: str = None
    up: str = None
    copies: int = 1
    priority: int = 0
    source: str = None


# key -> (kind, strictly positive?)
_SIDECAR_SCHEMA = {"size_mm": ("float", True), "pixel_mm": ("float", True),
                   "height_mm": ("float", True), "height_scale": ("float", True),
                   "profile": ("str", False), "max_fill_mm": ("float", False),
                   "min_prominence_mm": ("float", False), "smooth_mm": ("float", False),
                   "copies": ("int", True), "fit": ("str", False), "method": ("str", False),
                   "up": ("str", False), "priority": ("int", None)}


# A sidecar holds a few keys; anything larger is refused unparsed.
MAX_SIDECAR_BYTES = 64 * 1024


def sidecar_path(path):
    """``NAME.yaml`` beside input ``NAME.ext``: Path."""
    path = Path(path)
    return path.with_name(path.stem + ".yaml")


def load_sidecar(path):
    """Parse and check a sidecar YAML file: :class:`Sidecar`.

    A missing file gives ``Sidecar()`` (all defaults, ``source=None``).
    """
    path = Path(path)
    if not path.is_file():
        return Sidecar()
    src = str(path)
    try:
        data = yaml.safe_load(_read_capped(path, src))
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        mark = getattr(exc, "problem_mark", None)
        raise InvalidSidecar("not valid YAML: %s" % getattr(exc, "problem", exc),
                             code="sidecar.yaml", file=src,
                             where=mark and "line %d" % (mark.line + 1),
                             fix="fix the YAML syntax, e.g. `size_mm: 150`") from None
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise InvalidSidecar("a sidecar must be a mapping of keys", code="sidecar.type",
                             file=src, fix="write `key: value` lines, e.g. `size_mm: 150`")
    vals = {}
    for key, value in data.items():
        if key not in _SIDECAR_SCHEMA:
            raise InvalidSidecar("unknown sidecar key %r" % key, code="sidecar.unknown_key",
                                 file=src, where=str(key),
                                 fix="use only: " + ", ".join(_SIDECAR_SCHEMA))
        kind, positive = _SIDECAR_SCHEMA[key]
        vals[key] = _sidecar_value(key, value, kind, positive, src)
    for a, b in (("size_mm", "pixel_mm"), ("height_mm", "height_scale")):
        if a in vals and b in vals:
            raise InvalidSidecar("give either %s or %s, not both" % (a, b),
                                 code="sidecar.conflict", file=src, where=b,
                                 fix="remove one of them")
    return Sidecar(**vals, source=src)


def _read_capped(path, src):
    """The sidecar's text, refused past :data:`MAX_SIDECAR_BYTES` before it is parsed: a
    sidecar holds a few keys, and parsing megabytes would stall the daemon's intake. The
    size is looked at before the file is opened, and no more than the limit is read even
    if it grows meanwhile."""
    try:
        size = path.stat().st_size
        if size <= MAX_SIDECAR_BYTES:
            with open(path, "rb") as f:
                data = f.read(MAX_SIDECAR_BYTES + 1)
            size = max(size, len(data))
    except OSError as exc:
        raise InvalidSidecar("cannot read the sidecar: %s" % (exc.strerror or exc),
                             code="sidecar.unreadable", file=src,
                             fix="make it readable to the user hostd runs as, or remove it"
                             ) from None
    if size > MAX_SIDECAR_BYTES:
        raise InvalidSidecar("the sidecar is %d bytes; a sidecar may have at most %d (%d KiB)"
                             % (size, MAX_SIDECAR_BYTES, MAX_SIDECAR_BYTES // 1024),
                             code="sidecar.too_large", file=src,
                             fix="a sidecar holds a few `key: value` lines (docs/sidecar.md); "
                                 "write only those")
    return data.decode("utf-8")


# A profile is named, never given by path: a sidecar comes from anyone who can write
# to the drop folder, and a path would make the node read (and report) any file.
_PROFILE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")


# Keys with a few words allowed: (the words, the fix that explains them).
_CHOICES = {
    "fit": (("auto", "relief", "off"),
            "write `fit: auto` (smooth or lower the relief until it forms), `fit: relief` "
            "(only lower it) or `fit: off` (plan the relief as given)"),
    "method": (("isoline", "free"), "write `method: isoline` (paths along the isolines: domes "
                                    "and caps) or `method: free` (a print direction per "
                                    "triangle: also saddles, valleys, real terrain)"),
    "up": (("x", "y", "z", "-x", "-y", "-z"),
           "write the axis the mesh's top faces, e.g. `up: y` for an OBJ from Blender, "
           "`up: z` for most STL, `up: -z` for one upside down"),
}


def _sidecar_value(key, value, kind, positive, src):
    if key == "fit" and isinstance(value, bool):
        value = "auto" if value else "off"      # YAML reads a bare off as false
    if key == "up" and isinstance(value, str):
        value = value.strip().lower()
        value = value[1:] if value.startswith("+") else value
    if kind == "str":
        if not isinstance(value, str) or not value:
            raise InvalidSidecar("%s must be a non-empty string" % key,
                                 code="sidecar.type", file=src, where=key,
                                 fix="write e.g. `profile: generic-0.5mm`")
        if key in _CHOICES and value not in _CHOICES[key][0]:
            raise InvalidSidecar("%s must be %s" % (key, " or ".join(_CHOICES[key][0])),
                                 code="sidecar.value", file=src, where=key,
                                 fix=_CHOICES[key][1])
        if key == "profile" and (not _PROFILE_NAME.fullmatch(value)
                                 or value.endswith((".yaml", ".yml"))):
            raise InvalidSidecar("profile must be the name of a profile this node has, "
                                 "not a path or file name", code="sidecar.profile", file=src,
                                 where=key, fix="write the profile's name, e.g. "
                                 "`profile: generic-0.5mm` (the printers' profiles are in hostd.yaml)")
        return value
    is_int = isinstance(value, int) and not isinstance(value, bool)
    if kind == "int" and not is_int:
        raise InvalidSidecar("%s must be an integer, got %r" % (key, value),
                             code="sidecar.type", file=src, where=key,
                             fix="write a whole number")
    if not (is_int or isinstance(value, float)):
        raise InvalidSidecar("%s must be a number, got %r" % (key, value),
                             code="sidecar.type", file=src, where=key,
                             fix="write a plain number in mm, e.g. `%s: 2.0`" % key)
    if not np.isfinite(value) or (positive and value <= 0) or (positive is False and value < 0):
        raise InvalidSidecar("%s = %r is out of range" % (key, value), code="sidecar.value",
                             file=src, where=key,
                             fix="use a number %s 0" % (">" if positive else ">="))
    return int(value) if kind == "int" else float(value)


def settings(sidecar, profile=None):
    """Effective per-file options: sidecar over profile over built-in defaults.

    Returns dict with ``max_fill_mm``, ``min_prominence_mm``, ``smooth_mm``.
    """
    vp, mp = (profile.validate, profile.mesh) if profile is not None else (ValidateParams(),
                                                                           MeshParams())
    out = {"max_fill_mm": vp.max_fill_mm, "min_prominence_mm": mp.min_prominence_mm,
           "smooth_mm": mp.smooth_mm}
    for k in ("max_fill_mm", "min_prominence_mm", "smooth_mm"):
        if getattr(sidecar, k) is not None:
            out[k] = getattr(sidecar, k)
    return out
