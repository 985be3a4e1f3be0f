"""A profile written back out: its canonical content, the hash plans are cached by, and
YAML text with changes applied (``hostd calibrate`` writes calibrated profiles with it)."""

import copy
import hashlib
import json
from dataclasses import fields

import yaml

from pipeline.profiles.profile import parse_profile
from pipeline.profiles.schema import Profile


def profile_dict(profile):
    """The profile's full content with defaults filled in, as plain YAML-able data."""
    out = {}
    for f in fields(Profile):
        kind = f.metadata.get("kind")
        v = getattr(profile, f.name)
        if kind == "section":
            out[f.name] = {g.name: getattr(v, g.name) for g in fields(v)}
        elif kind == "pair":
            out[f.name] = [float(x) for x in v]
        elif kind == "curve":
            out[f.name] = {"degree": int(v.degree),
                           "points": [[float(t), float(s)] for t, s in zip(v.thickness_mm, v.shrink)]}
        elif kind:
            out[f.name] = v
    return out


def profile_hash(profile):
    """sha256 hex digest of the profile's canonical content (for plan caching)."""
    text = json.dumps(profile_dict(profile), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


class _Dumper(yaml.SafeDumper):
    pass


def _str_presenter(dumper, s):
    style = "|" if "\n" in s else None
    return dumper.represent_scalar("tag:yaml.org,2002:str", s, style=style)


_Dumper.add_representer(str, _str_presenter)


def _merge(base, changes):
    for k, v in changes.items():
        if isinstance(v, dict) and isinstance(base.get(k), dict):
            _merge(base[k], v)
        else:
            base[k] = v
    return base


def profile_to_yaml(profile, comment=None, **changes):
    """YAML text of ``profile`` with ``changes`` applied (validated before returning).

    ``changes`` are top-level keys; mappings merge into sections, e.g.
    ``profile_to_yaml(p, shrink_curve={"points": [[0.1, 0.3], ...]},
    shrink_limits={"s_max": 0.3})``. ``comment`` lines go on top as ``# ...``.
    """
    data = _merge(profile_dict(profile), copy.deepcopy(changes))
    parse_profile(copy.deepcopy(data), source=profile.source or None)
    text = yaml.dump(data, Dumper=_Dumper, sort_keys=False, default_flow_style=None,
                     allow_unicode=True, width=100)
    if comment:
        text = "".join("# " + line + "\n" for line in str(comment).splitlines()) + text
    return text
