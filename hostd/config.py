"""The daemon's configuration: ``hostd.yaml`` validated into a frozen ``Config``.

Without a file, the embedded default (``hostd/defaults/hostd.yaml``) is used: folders
under ``./hostd-data/``, one printer on the built-in simulator. A config file is
merged over that default, so it only needs the keys it changes. Unknown keys and
wrong types are :class:`HostdError` naming the key and the file. Relative folders
are resolved against the config file's folder (the current folder for the default).
"""

import os
import re
import socket
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

import yaml

from hostd.errors import HostdError

DEFAULT_PATH = Path(__file__).resolve().parent / "defaults" / "hostd.yaml"
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")


@dataclass(frozen=True)
class PrinterConfig:
    """One printer: ``port`` is a device path, pyserial URL or ``sim://?options``."""
    name: str
    profile: str = "generic-0.5mm"
    port: str = "sim://"
    baud: int = 115200


@dataclass(frozen=True)
class WebConfig:
    """Status page; carried here so one file configures the node."""
    host: str = "127.0.0.1"
    port: int = 8080
    token: str = None
    # Host header names the page answers to besides localhost, IP addresses, this machine's
    # name and web.host (a name a browser was led to by a stranger's DNS is refused).
    allowed_hosts: tuple = ()
    announce: bool = None     # zeroconf; None: when the page listens beyond localhost


@dataclass(frozen=True)
class PlanningConfig:
    """Planning worker processes and the limits of one plan."""
    workers: int = 1
    time_limit_s: float = 600.0
    memory_mb: int = 4096


@dataclass(frozen=True)
class Config:
    node_id: str
    drop_dir: Path
    state_dir: Path
    outbox_dir: Path
    done_dir: Path
    failed_dir: Path
    printers: tuple = ()
    web: WebConfig = field(default_factory=WebConfig)
    settle_s: float = 2.0
    poll_s: float = 2.0
    lease_s: float = 60.0
    heartbeat_s: float = 5.0
    stop_timeout_s: float = 20.0
    claim_ahead: int = 2
    planning: PlanningConfig = field(default_factory=PlanningConfig)
    source: str = None

    @property
    def db_path(self):
        return self.state_dir / "jobs.sqlite"

    @property
    def lock_path(self):
        return self.state_dir / "hostd.pid"

    @property
    def spool_dir(self):
        """Local copies of the G-code being printed (the outbox may be on the share)."""
        return self.state_dir / "spool"

    def printer(self, name):
        for p in self.printers:
            if p.name == name:
                return p
        return None


# key -> (type, lower bound or None); nested sections are handled separately.
_TOP = {"node_id": (str, None), "drop_dir": (str, None), "state_dir": (str, None),
        "outbox_dir": (str, None), "done_dir": (str, None), "failed_dir": (str, None),
        "settle_s": (float, 0.0), "poll_s": (float, 0.05), "lease_s": (float, 1.0),
        "heartbeat_s": (float, 0.05), "stop_timeout_s": (float, 1.0), "claim_ahead": (int, 1)}
_SECTIONS = {"web": WebConfig, "planning": PlanningConfig}
_LIMITS = {"workers": 1, "time_limit_s": 0.1, "memory_mb": 64, "port": 0, "baud": 1}


def _type_ok(value, kind):
    if kind is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if kind is int:
        return isinstance(value, int) and not isinstance(value, bool)
    return isinstance(value, kind)


def _check(value, kind, key, src, lo=None, nullable=False):
    if value is None and nullable:
        return None
    if kind is tuple:
        if not isinstance(value, list) or not all(isinstance(v, str) and v for v in value):
            raise HostdError("%s must be a list of host names" % key,
                             code="config.type", file=src, key=key,
                             fix="write e.g. `%s: [printers.example.org]`" % key.rsplit(".", 1)[-1])
        return tuple(value)
    if not _type_ok(value, kind):
        raise HostdError("%s must be %s, got %r" % (key, {float: "a number", int: "an integer",
                                                          str: "a string",
                                                          bool: "true or false"}[kind], value),
                         code="config.type", file=src, key=key,
                         fix="write e.g. `%s: %s`" % (key.rsplit(".", 1)[-1],
                                                      {float: "2.0", int: "1", str: "text",
                                                      bool: "false"}[kind]))
    if lo is not None and kind is not str and value < lo:
        raise HostdError("%s = %r is too small (at least %s)" % (key, value, lo),
                         code="config.value", file=src, key=key, fix="use a value >= %s" % lo)
    return float(value) if kind is float else value


def _unknown(key, known, src):
    return HostdError("unknown key %r" % key, code="config.unknown_key", file=src, key=key,
                      fix="use only: " + ", ".join(known))


def _section(cls, data, prefix, src):
    if not isinstance(data, dict):
        raise HostdError("%s must be a mapping" % prefix, code="config.type", file=src, key=prefix)
    known = {f.name: f for f in fields(cls)}
    values = {}
    for key, value in data.items():
        if key not in known:
            raise _unknown("%s.%s" % (prefix, key), list(known), src)
        kind = known[key].type
        values[key] = _check(value, kind, "%s.%s" % (prefix, key), src, _LIMITS.get(key),
                             nullable=known[key].default is None)
    try:
        return cls(**values)
    except TypeError:
        missing = [f.name for f in fields(cls) if f.name not in values]
        raise HostdError("%s needs %s" % (prefix, ", ".join(missing)), code="config.missing",
                         file=src, key=prefix) from None


def _printers(data, src):
    if not isinstance(data, list) or not data:
        raise HostdError("printers must be a non-empty list", code="config.type", file=src,
                         key="printers", fix="write `printers: [{name: p1, port: sim://}]`")
    out, seen, ports = [], set(), {}
    for i, item in enumerate(data):
        p = _section(PrinterConfig, item, "printers[%d]" % i, src)
        # Each sim:// is a printer of its own; a device (through any of its symlinks) is one.
        device = None if "://" in p.port else os.path.realpath(p.port)
        if device in ports:
            raise HostdError("printers %r and %r use the same port %s" % (ports[device], p.name, p.port),
                             code="config.value", file=src, key="printers[%d].port" % i,
                             fix="give each printer its own port (/dev/serial/by-id/... names "
                                 "stay put when USB devices are replugged)")
        if device is not None:
            ports[device] = p.name
        if not _NAME.match(p.name):
            raise HostdError("printer name %r is not a plain name" % p.name, code="config.value",
                             file=src, key="printers[%d].name" % i,
                             fix="use letters, digits, '-', '_' or '.', e.g. `mk3-left`")
        if p.name in seen:
            raise HostdError("two printers are named %r" % p.name, code="config.value", file=src,
                             key="printers[%d].name" % i, fix="give each printer its own name")
        seen.add(p.name)
        out.append(p)
    return tuple(out)


def _read_yaml(path):
    try:
        data = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        raise HostdError("cannot read the config file: %s" % exc.strerror, code="config.unreadable",
                         file=path, fix="check the path given to --config") from None
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        mark = getattr(exc, "problem_mark", None)
        raise HostdError("not valid YAML: %s%s" % (getattr(exc, "problem", exc),
                                                   " at line %d" % (mark.line + 1) if mark else ""),
                         code="config.yaml", file=path, fix="fix the YAML syntax") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise HostdError("the config must be a mapping of keys", code="config.type", file=path,
                         fix="write `key: value` lines, e.g. `poll_s: 2`")
    return data


def parse_config(data, source=None, base_dir=None, defaults=None):
    """Validate a config mapping (merged over ``defaults``) into a :class:`Config`."""
    src = str(source) if source else "<config>"
    merged = dict(defaults or {})
    for key, value in data.items():
        if key in _SECTIONS and isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = dict(merged[key], **value)
        else:
            merged[key] = value
    known = list(_TOP) + list(_SECTIONS) + ["printers"]
    values = {}
    for key, value in merged.items():
        if key not in known:
            raise _unknown(key, known, src)
        if key in _SECTIONS:
            values[key] = _section(_SECTIONS[key], value, key, src)
        elif key == "printers":
            values[key] = _printers(value, src)
        else:
            kind, lo = _TOP[key]
            values[key] = _check(value, kind, key, src, lo, nullable=key == "node_id")
    base = Path(base_dir) if base_dir else Path.cwd()
    for key in ("drop_dir", "state_dir", "outbox_dir", "done_dir", "failed_dir"):
        if key not in values:
            raise HostdError("%s is missing" % key, code="config.missing", file=src, key=key)
        values[key] = (base / os.path.expanduser(values[key])).resolve()
    node = values.get("node_id") or socket.gethostname().split(".")[0] or "node"
    if not _NAME.match(node):
        raise HostdError("node_id %r is not a plain name" % node, code="config.value", file=src,
                         key="node_id", fix="use letters, digits, '-', '_' or '.'")
    values["node_id"] = node
    if "printers" not in values:
        raise HostdError("no printers configured", code="config.missing", file=src, key="printers")
    return Config(source=source and str(source), **values)


def default_data():
    return _read_yaml(DEFAULT_PATH)


def load_config(path=None, **overrides):
    """The config from ``path`` merged over the embedded default (or the default alone).

    ``overrides`` replace fields after validation (tests, ``--node-id``).
    """
    defaults = default_data()
    if path is None:
        config = parse_config({}, DEFAULT_PATH, Path.cwd(), defaults)
    else:
        path = Path(path)
        data = _read_yaml(path)
        config = parse_config(data, path, path.resolve().parent, defaults)
    return replace(config, **overrides) if overrides else config


def check_profiles(config):
    """Every printer's profile loads: a misspelt or broken profile is a configuration
    error when the daemon starts, not a printer that keeps failing to connect."""
    from pipeline.errors import PipelineError
    from pipeline.profiles.profile import load_profile
    for i, p in enumerate(config.printers):
        try:
            load_profile(p.profile)
        except PipelineError as exc:
            where = "profile %s: " % exc.file if exc.file else ""
            raise HostdError("printer %r: %s%s" % (p.name, where, exc.message), code="config.profile",
                             file=config.source, key="printers[%d].profile" % i,
                             fix=exc.fix) from None
