"""Options of the simulated printer, shared by ``sim://`` URLs and ``hostd sim-printer``.

Every field below is a ``sim://`` query option (``sim://?advanced_ok=1&planner=16``) and a
``hostd sim-printer`` flag (``--advanced-ok 1 --planner 16``):

==================== ======== ==========================================================
option               default  meaning
==================== ======== ==========================================================
advanced_ok          0        report ``Cap:ADVANCED_OK:1`` and answer ``ok N<n> P<p> B<b>``
planner              16       planner buffer, moves (Marlin BLOCK_BUFFER_SIZE)
bufsize              4        command queue, lines (Marlin BUFSIZE)
rx_bytes             128      serial receive buffer, bytes (Marlin RX_BUFFER_SIZE);
                              bytes arriving while it is full are dropped (overrun)
baud                 0        byte rate of the simulated wire, baud/10 bytes/s each way;
                              0 = take the baud the host link uses (sim://) or 115200
time_scale           1.0      moves, dwells and heating take real duration x time_scale
                              (0 = instantaneous)
seed                 0        seed of the fault injection
boot_s               0.2      delay between the port opening and the ``start`` banner
autoreport           1        AUTOREPORT_TEMP (M155) capability
emergency_parser     1        EMERGENCY_PARSER: M112 acts on arrival, even if queues are full
keepalive_s          2.0      ``echo:busy: processing`` interval while blocked (real time)
hotend_tau_s         20.0     first-order heating time constant of the hotend (scaled)
bed_tau_s            60.0     first-order heating time constant of the bed (scaled)
fault_corrupt        0        probability per received line that one byte is corrupted
fault_lost_ok        0        probability that an ``ok`` is never sent
fault_noise          0        probability per reply that a garbage line precedes it
fault_reset_line     0        spurious reset (new ``start`` banner) on executing line N
fault_disconnect_line 0       the port disappears on executing line N ...
reconnect_s          0.5      ... and returns after this many seconds (new pty, same link)
fault_runaway_line   0        thermal runaway on executing line N (firmware halts)
fault_stall_line     0        the firmware stops answering on executing line N ...
stall_s              60       ... for this many seconds (real time), then carries on where
                              it was, as a board whose main loop hung and recovered
==================== ======== ==========================================================

Line-triggered faults fire once; line numbers are the host's ``N`` numbers.
"""

import dataclasses
from dataclasses import dataclass
from urllib.parse import parse_qsl, urlsplit

from hostd.printer.errors import PrinterError


@dataclass
class SimConfig:
    """Simulated printer options (see the module docstring for their meaning)."""

    advanced_ok: bool = False
    planner: int = 16
    bufsize: int = 4
    rx_bytes: int = 128
    baud: int = 0
    time_scale: float = 1.0
    seed: int = 0
    boot_s: float = 0.2
    autoreport: bool = True
    emergency_parser: bool = True
    keepalive_s: float = 2.0
    hotend_tau_s: float = 20.0
    bed_tau_s: float = 60.0
    fault_corrupt: float = 0.0
    fault_lost_ok: float = 0.0
    fault_noise: float = 0.0
    fault_reset_line: int = 0
    fault_disconnect_line: int = 0
    reconnect_s: float = 0.5
    fault_runaway_line: int = 0
    fault_stall_line: int = 0
    stall_s: float = 60.0

    @classmethod
    def from_url(cls, url):
        """Build from ``sim://[name]?opt=value&...``; unknown options are an error."""
        parts = urlsplit(url)
        if parts.scheme != "sim":
            raise PrinterError("config", "not a sim:// URL: %r" % url)
        return cls.from_pairs(parse_qsl(parts.query, keep_blank_values=True))

    @classmethod
    def from_pairs(cls, pairs):
        """Build from (name, text value) pairs, converting to each field's type."""
        types = {f.name: f.type for f in dataclasses.fields(cls)}
        values = {}
        for name, text in pairs:
            name = name.replace("-", "_")
            if name not in types:
                raise PrinterError("config", "unknown simulator option %r (known: %s)"
                                   % (name, ", ".join(sorted(types))))
            values[name] = _convert(types[name], text, name)
        return cls(**values)

    @classmethod
    def add_arguments(cls, parser, exclude=("baud",)):
        """Add one ``--option VALUE`` flag per field to an argparse parser.

        ``baud`` is left out by default: ``hostd sim-printer --baud`` is its own flag.
        """
        for f in dataclasses.fields(cls):
            if f.name in exclude:
                continue
            parser.add_argument("--" + f.name.replace("_", "-"), dest="sim_" + f.name,
                                default=None, metavar=_type_name(f.type),
                                help="simulator option %s (default %s)" % (f.name, f.default))

    @classmethod
    def from_args(cls, args, **overrides):
        """Build from parsed argparse flags added by :meth:`add_arguments`."""
        pairs = [(f.name, getattr(args, "sim_" + f.name)) for f in dataclasses.fields(cls)
                 if getattr(args, "sim_" + f.name, None) is not None]
        config = cls.from_pairs(pairs)
        return dataclasses.replace(config, **overrides)


def _type_name(kind):
    return {"bool": "0|1", "int": "N", "float": "X"}.get(getattr(kind, "__name__", kind), "V")


def _convert(kind, text, name):
    kind = getattr(kind, "__name__", kind)
    try:
        if kind == "bool":
            low = str(text).strip().lower()
            if low in ("1", "true", "yes", "on", ""):
                return True
            if low in ("0", "false", "no", "off"):
                return False
            raise ValueError(text)
        if kind == "int":
            return int(text)
        return float(text)
    except ValueError:
        raise PrinterError("config", "bad value %r for simulator option %s" % (text, name)) from None
