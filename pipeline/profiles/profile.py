"""Printer profiles: one YAML file per printer set-up, validated into a frozen ``Profile``.

The schema lives in :mod:`pipeline.profiles.schema` (one dataclass per YAML section,
field metadata gives type, bounds and default) and is documented in
``profiles/README.md``; this module reads a file into it.
Unknown keys, wrong types and physically inconsistent values are
:class:`pipeline.errors.InvalidProfile` errors naming the file and key path.

Lookup order for a profile name (``load_profile("generic-0.5mm")``):
``search_dirs``, then the dirs in env ``HOSTD_PROFILES`` (``os.pathsep``
separated), then the repo's ``profiles/``, then ``sys.prefix/share/hostd/profiles``.
"""

import copy
import os
import re
import string
import sys
from dataclasses import MISSING, fields
from pathlib import Path

import numpy as np
import yaml

from pipeline.errors import InvalidProfile
from pipeline.profiles.schema import GCODE_PLACEHOLDERS, GcodeTemplates, Profile, ShrinkLimits, _num
from pipeline.profiles.shrink import ShrinkCurve

# s_min/s_max may lie outside the fitted curve by this much (fit noise, half a percent
# of shrink) before we clamp them to it.
_SHRINK_TOLERANCE = 5e-3


def _err(msg, code, src, where, fix):
    return InvalidProfile(msg, code=code, file=src, where=where, fix=fix)


_KEYLIKE = re.compile(r"[A-Za-z_][A-Za-z0-9_]{0,39}")


def _got(value):
    """What a wrong value is, without its text: a profile error is shown on pages and in
    files others read, and the file it came from may not be a profile at all."""
    if isinstance(value, bool):
        return "got true/false"
    if isinstance(value, (int, float, np.integer, np.floating)):
        return "got the number %g" % value
    if isinstance(value, str):
        return "got text"
    if isinstance(value, (list, tuple)):
        return "got a list of %d items" % len(value)
    if isinstance(value, dict):
        return "got a mapping"
    return "got %s" % type(value).__name__


def _type_name(kind):
    return {"float": "a number", "int": "an integer", "str": "a string",
            "section": "a mapping", "pair": "a list of two numbers"}.get(kind, kind)


def _check_value(value, f, key, src):
    """Type and bound check of one scalar field; returns the converted value."""
    m = f.metadata
    kind = m["kind"]
    if kind == "str":
        if not isinstance(value, str):
            raise _err("%s must be a string, %s" % (key, _got(value)), "profile.type", src, key,
                       "quote the value")
        if m["choices"] and value not in m["choices"]:
            raise _err("%s must be one of %s" % (key, ", ".join(m["choices"])),
                       "profile.value", src, key, "use one of " + ", ".join(m["choices"]))
        return value
    if value is None and m.get("nullable"):
        return None
    is_int = isinstance(value, (int, np.integer)) and not isinstance(value, bool)
    is_num = is_int or (isinstance(value, (float, np.floating)) and not isinstance(value, bool))
    if kind == "int" and not is_int:
        raise _err("%s must be an integer, %s" % (key, _got(value)), "profile.type", src, key,
                   "write a whole number without a decimal point")
    if not is_num:
        raise _err("%s must be a number%s, %s" % (key, " or null" if m.get("nullable") else "",
                                                  _got(value)), "profile.type", src, key,
                   "write a plain number (YAML reads 1e-3 as text; write 0.001)")
    v = int(value) if kind == "int" else float(value)
    lo, hi = m["lo"], m["hi"]
    if not np.isfinite(v) or (v <= lo if m["strict"] else v < lo) or (hi is not None and v > hi):
        rng = "%s %g" % (">" if m["strict"] else ">=", lo)
        if hi is not None:
            rng += " and <= %g" % hi
        raise _err("%s = %g is out of range (must be %s)" % (key, v, rng), "profile.value",
                   src, key, "use a value %s" % rng)
    return v


def _build(cls, data, path, src):
    """Build dataclass ``cls`` from mapping ``data`` at key path ``path``."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise _err("%s must be a mapping of keys, %s" % (path or "the profile", _got(data)),
                   "profile.type", src, path or "/", "write it as `key: value` lines")
    schema = [f for f in fields(cls) if f.metadata.get("kind")]
    known = {f.name for f in schema}
    unknown = [k for k in data if k not in known]
    if unknown:
        # A key is named only when it looks like one (a misspelt `prnt`), never a line
        # of some other file read as YAML.
        name = unknown[0] if _KEYLIKE.fullmatch(str(unknown[0])) else None
        key = (path + "." if path else "") + name if name else (path or "/")
        raise _err("unknown key %s" % (repr(key) if name else "in " + (path or "the profile")),
                   "profile.unknown_key", src, key,
                   "remove it or use one of: " + ", ".join(sorted(known)))
    out = {}
    for f in schema:
        key = (path + "." if path else "") + f.name
        if f.name not in data:
            if f.default is MISSING and f.default_factory is MISSING:
                raise _err("missing required key %r" % key, "profile.missing_key", src, key,
                           "add `%s:` (see profiles/README.md)" % key)
            continue
        value, kind = data[f.name], f.metadata["kind"]
        if kind == "section":
            out[f.name] = _build(f.metadata["cls"], value, key, src)
        elif kind == "pair":
            out[f.name] = _pair(value, key, src)
        elif kind == "curve":
            out[f.name] = value  # fitted later, once the thickness range is known
        else:
            out[f.name] = _check_value(value, f, key, src)
    return out if cls is Profile else cls(**out)


def _pair(value, key, src):
    if not (isinstance(value, (list, tuple)) and len(value) == 2):
        raise _err("%s must be a list of two numbers [x, y], %s" % (key, _got(value)),
                   "profile.type", src, key, "write e.g. [220, 220]")
    f = _num()
    return tuple(_check_value(v, f, "%s[%d]" % (key, i), src) for i, v in enumerate(value))


def _curve(value, trange, src):
    """Fit the ShrinkCurve from ``shrink_curve: {degree, points}``."""
    key = "shrink_curve"
    if not isinstance(value, dict):
        raise _err("shrink_curve must be a mapping {degree, points}", "profile.type", src, key,
                   "write shrink_curve: {degree: 4, points: [[0.1, 0.343], ...]}")
    if any(k not in ("degree", "points") for k in value):
        raise _err("unknown key in shrink_curve", "profile.unknown_key", src, key,
                   "keep only degree and points there")
    if "points" not in value:
        raise _err("missing required key 'shrink_curve.points'", "profile.missing_key", src,
                   key + ".points", "list the measured [thickness_mm, shrink] pairs")
    degree = _check_value(value.get("degree", 4), _num(lo=1, strict=False, hi=8, integer=True),
                          key + ".degree", src)
    pts = value["points"]
    num = _num(lo=-1.0, strict=False)  # sign and range are ShrinkCurve's business
    if not isinstance(pts, list) or not all(isinstance(p, (list, tuple)) and len(p) == 2
                                            for p in pts):
        raise _err("shrink_curve.points must be a list of [thickness_mm, shrink] pairs",
                   "profile.type", src, key + ".points", "write [[0.1, 0.343], [0.15, 0.28], ...]")
    arr = np.array([[_check_value(v, num, "%s.points[%d][%d]" % (key, i, j), src)
                     for j, v in enumerate(p)] for i, p in enumerate(pts)], dtype=float)
    arr = arr.reshape(-1, 2)
    return ShrinkCurve(arr[:, 0], arr[:, 1], degree=degree,
                       theta_range_mm=(trange.min, trange.max), source=src)


def parse_profile(data, source=None):
    """Validate a parsed YAML mapping into a :class:`Profile`.

    Parameters
    ----------
    data : dict
        The profile as parsed from YAML.
    source : str or Path, optional
        File name for messages; also stored as ``Profile.source``.
    """
    src = None if source is None else str(source)
    raw = copy.deepcopy(data)
    vals = _build(Profile, data, "", src)
    trange = vals["thickness_mm"]
    if not trange.min < trange.max:
        raise _err("thickness_mm.min (%g) must be below thickness_mm.max (%g)"
                   % (trange.min, trange.max), "profile.value", src, "thickness_mm",
                   "set min below max")
    if trange.max > vals["nozzle_mm"]:
        raise _err("thickness_mm.max (%g mm) exceeds the nozzle diameter (%g mm)"
                   % (trange.max, vals["nozzle_mm"]), "profile.value", src, "thickness_mm.max",
                   "layers thicker than the nozzle do not extrude reliably; lower it")
    ratio = vals["path_width_mm"] / vals["nozzle_mm"]
    if not 0.6 <= ratio <= 2.0:
        raise _err("path_width_mm (%g) is implausible for a %g mm nozzle (ratio %.2f)"
                   % (vals["path_width_mm"], vals["nozzle_mm"], ratio), "profile.value", src,
                   "path_width_mm", "use roughly 0.9-1.2 times the nozzle diameter")
    curve = _curve(vals["shrink_curve"], trange, src)
    vals["shrink_curve"] = curve
    warnings = []
    if curve.thickness_mm.min() > trange.min + 1e-9 or curve.thickness_mm.max() < trange.max - 1e-9:
        warnings.append("thickness_mm range %g..%g mm extends beyond the measured thicknesses "
                        "%g..%g mm; the shrink curve is extrapolated there"
                        % (trange.min, trange.max, curve.thickness_mm.min(),
                           curve.thickness_mm.max()))
    limits = vals.get("shrink_limits", ShrinkLimits())
    s_min, s_max = limits.s_min, limits.s_max
    if not s_min < s_max:
        raise _err("shrink_limits.s_min (%g) must be below s_max (%g)" % (s_min, s_max),
                   "profile.value", src, "shrink_limits", "set s_min below s_max")
    c_lo, c_hi = curve.sigma_range
    explicit = isinstance(data.get("shrink_limits"), dict)
    if s_max > c_hi + _SHRINK_TOLERANCE:
        if explicit and "s_max" in data["shrink_limits"]:
            warnings.append("shrink_limits.s_max %.4g clamped to %.4g, the most the shrink curve "
                            "reaches on thickness_mm" % (s_max, c_hi))
        s_max = c_hi
    if s_min < c_lo - _SHRINK_TOLERANCE:
        if explicit and "s_min" in data["shrink_limits"]:
            warnings.append("shrink_limits.s_min %.4g clamped to %.4g, the least the shrink "
                            "curve reaches on thickness_mm" % (s_min, c_lo))
        s_min = c_lo
    if not s_min < s_max:
        raise _err("shrink_limits %g..%g lie outside the shrink curve's range %.4g..%.4g"
                   % (limits.s_min, limits.s_max, c_lo, c_hi), "profile.value", src,
                   "shrink_limits", "set s_min/s_max within the measured shrink range")
    vals["shrink_limits"] = ShrinkLimits(s_min, s_max)
    gcode = vals.get("gcode", GcodeTemplates())
    for f in fields(GcodeTemplates):
        _check_placeholders(getattr(gcode, f.name), "gcode." + f.name, src)
    if vals.get("bed_clear") == "auto" and not _has_commands(gcode.clear_bed):
        raise _err("bed_clear is auto but gcode.clear_bed has no G-code: the next print would "
                   "start on the part before", "profile.bed_clear", src, "bed_clear",
                   "add gcode.clear_bed: the G-code that takes the finished part off the bed "
                   "(a belt, a sweep), or set bed_clear: person (a person says the bed is clear)")
    return Profile(**vals, source=src or "", raw=raw, warnings=tuple(warnings))


def _has_commands(text):
    """Whether a G-code snippet has a command besides comments and blank lines."""
    return any(line.split(";", 1)[0].strip() for line in text.splitlines())


def _check_placeholders(template, key, src):
    try:
        names = [p[1] for p in string.Formatter().parse(template) if p[1] is not None]
    except ValueError as exc:
        raise _err("%s is not a valid template: %s" % (key, exc), "profile.value", src, key,
                   "write literal braces as {{ and }}") from None
    bad = [n for n in names if n not in GCODE_PLACEHOLDERS]
    if bad:
        raise _err("%s uses unknown placeholder {%s}" % (key, bad[0]), "profile.value", src, key,
                   "use one of " + ", ".join("{%s}" % p for p in GCODE_PLACEHOLDERS))


def profile_search_dirs(search_dirs=None):
    """The directories searched for profile names, in order: list of Path."""
    dirs = [Path(d) for d in (search_dirs or [])]
    env = os.environ.get("HOSTD_PROFILES", "")
    dirs += [Path(d) for d in env.split(os.pathsep) if d]
    import pipeline
    dirs.append(Path(pipeline.__file__).resolve().parent.parent / "profiles")
    dirs.append(Path(sys.prefix) / "share" / "hostd" / "profiles")
    return dirs


def _looks_like_path(s):
    return os.sep in s or (os.altsep and os.altsep in s) or s.endswith((".yaml", ".yml"))


def find_profile(name_or_path, search_dirs=None):
    """Path of the profile file for a name or path; raises ``profile.not_found``."""
    s = str(name_or_path)
    p = Path(s).expanduser()
    if isinstance(name_or_path, Path) or _looks_like_path(s) or p.is_file():
        if p.is_file():
            return p
        raise _err("profile file not found", "profile.not_found", s, None,
                   "check the path, or give a profile name (see `list_profiles()`)")
    dirs = profile_search_dirs(search_dirs)
    for d in dirs:
        for ext in (".yaml", ".yml"):
            if (d / (s + ext)).is_file():
                return d / (s + ext)
    known = sorted(list_profiles(search_dirs))
    raise _err("no profile named %r in %s" % (s, ", ".join(str(d) for d in dirs)),
               "profile.not_found", None, s,
               "use one of: %s, or a path to a .yaml file" % (", ".join(known) or "(none found)"))


def load_profile(name_or_path, search_dirs=None):
    """Load and validate a profile by name or path: :class:`Profile`.

    Raises :class:`InvalidProfile` (``profile.not_found``, ``profile.yaml``,
    ``profile.unknown_key``, ``profile.type``, ``profile.missing_key``,
    ``profile.value``, ``profile.shrink_*``).
    """
    path = find_profile(name_or_path, search_dirs)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise _err("cannot read profile: %s" % exc, "profile.yaml", path, None,
                   "save it as UTF-8 text") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = "line %d, column %d" % (mark.line + 1, mark.column + 1) if mark else None
        raise _err("not valid YAML: %s" % getattr(exc, "problem", exc), "profile.yaml", path,
                   where, "fix the YAML syntax (indentation, quotes, colons)") from None
    if data is None:
        raise _err("profile is empty", "profile.yaml", path, None,
                   "copy a shipped profile from profiles/ and edit it")
    return parse_profile(data, source=path)


def list_profiles(search_dirs=None):
    """Profiles visible by name: dict name -> Path (earlier search dirs win), sorted by name."""
    found = {}
    for d in profile_search_dirs(search_dirs):
        if d.is_dir():
            for p in sorted(list(d.glob("*.yaml")) + list(d.glob("*.yml"))):
                found.setdefault(p.stem, p)
    return dict(sorted(found.items()))
