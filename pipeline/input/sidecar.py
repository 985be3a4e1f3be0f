"""The sidecar ``NAME.yaml`` beside an input: physical scale and per-file options.

Errors (``InvalidSidecar``): ``sidecar.yaml``, ``.unknown_key``, ``.type``, ``.value``,
``.conflict``, ``.profile``, ``.too_large`` (over :data:`MAX_SIDECAR_BYTES`, refused
unparsed), ``.unreadable``, ``.alias`` (YAML anchors and aliases, refused as parsed),
``.nested`` (deeper than :data:`MAX_DEPTH`); each names the file, the key and the fix.
A message shows at most a few dozen characters of a value it quotes (:func:`brief`).
"""

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import yaml

from pipeline.errors import InvalidSidecar
from pipeline.input.regular import opener
from pipeline.profiles.schema import MeshParams, ValidateParams


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
# A sidecar is one mapping of scalars: depth 2. Deeper only to say what is wrong.
MAX_DEPTH = 8
# The longest scalar a sidecar has use for (a profile name has 64 characters at most).
MAX_SCALAR_CHARS = 256
MAX_COPIES = 100
MAX_PRIORITY = 1000
# Numbers beyond this are no size, height or count of anything printed.
_HUGE = 1e12


def brief(value, limit=40):
    """``value`` as a message may quote it: a scalar's repr cut to ``limit`` characters, a
    list or mapping by its kind and length only (never formatted whole: a few hundred bytes
    of YAML can stand for gigabytes of text)."""
    if isinstance(value, (list, tuple)):
        return "a list of %d items" % len(value)
    if isinstance(value, dict):
        return "a mapping of %d keys" % len(value)
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) > 10 ** 30:
        return "an integer of %d digits" % len(str(abs(value)))
    text = repr(value) if isinstance(value, (str, int, float, bool, type(None))) else \
        "a value of type %s" % type(value).__name__
    return text if len(text) <= limit else text[:limit - 3] + "..."


class _Loader(yaml.SafeLoader):
    """PyYAML's safe loader, refusing anchors and aliases (``&a`` / ``*a``: eight levels of
    nine aliases each are 43 million values from 358 bytes) and nesting past
    :data:`MAX_DEPTH` (thousands of ``[`` exhaust the composer's recursion) before any
    value is built, and scalars longer than :data:`MAX_SCALAR_CHARS`."""

    depth = 0

    def compose_node(self, parent, index):
        event = self.peek_event()
        if isinstance(event, yaml.AliasEvent) or getattr(event, "anchor", None):
            raise _Refused("sidecar.alias", "YAML anchors and aliases (&name, *name) are not "
                           "read in a sidecar", event.start_mark,
                           "write each value out, e.g. `smooth_mm: 2.0`")
        if isinstance(event, yaml.ScalarEvent) and len(event.value) > MAX_SCALAR_CHARS:
            raise _Refused("sidecar.value", "a value of %d characters; a sidecar's values have "
                           "at most %d" % (len(event.value), MAX_SCALAR_CHARS),
                           event.start_mark, "write a short value, e.g. `size_mm: 150`")
        self.depth += 1
        try:
            if self.depth > MAX_DEPTH:
                raise _Refused("sidecar.nested", "values nested more than %d deep; a sidecar "
                               "is `key: value` lines" % MAX_DEPTH, event.start_mark,
                               "write plain `key: value` lines, e.g. `size_mm: 150`")
            return super().compose_node(parent, index)
        finally:
            self.depth -= 1


class _Refused(Exception):
    def __init__(self, code, message, mark, fix):
        super().__init__(message)
        self.code, self.message, self.mark, self.fix = code, message, mark, fix


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
        data = yaml.load(_read_capped(path, src), Loader=_Loader)
    except _Refused as exc:
        raise InvalidSidecar(exc.message, code=exc.code, file=src,
                             where=exc.mark and "line %d" % (exc.mark.line + 1),
                             fix=exc.fix) from None
    except ValueError as exc:
        # PyYAML turns an integer of more than 4300 digits into a ValueError of Python's.
        raise InvalidSidecar("a value cannot be read: %s" % brief(str(exc), 120),
                             code="sidecar.value", file=src,
                             fix="write plain numbers, e.g. `size_mm: 150`") from None
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
            raise InvalidSidecar("unknown sidecar key %s" % brief(key),
                                 code="sidecar.unknown_key", file=src,
                                 where=key if isinstance(key, str) and len(key) <= 40 else
                                 brief(key),
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
            # A FIFO or device planted under the name must not block the reader.
            with open(path, "rb", opener=opener) as f:
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
        raise InvalidSidecar("%s must be an integer, got %s" % (key, brief(value)),
                             code="sidecar.type", file=src, where=key,
                             fix="write a whole number")
    if not (is_int or isinstance(value, float)):
        raise InvalidSidecar("%s must be a number, got %s" % (key, brief(value)),
                             code="sidecar.type", file=src, where=key,
                             fix="write a plain number in mm, e.g. `%s: 2.0`" % key)
    bound = {"copies": MAX_COPIES, "priority": MAX_PRIORITY}.get(key)
    if bound is not None and abs(value) > bound:
        raise InvalidSidecar("%s = %s is more than a sidecar may ask" % (key, brief(value)),
                             code="sidecar.value", file=src, where=key,
                             fix="use a number from 1 to %d (drop the file again for more "
                                 "sheets)" % bound if key == "copies" else
                                 "use a number from -%d to %d" % (bound, bound))
    if abs(value) > _HUGE or not np.isfinite(value) or (positive and value <= 0) \
            or (positive is False and value < 0):
        raise InvalidSidecar("%s = %s is out of range" % (key, brief(value)),
                             code="sidecar.value", file=src, where=key,
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
