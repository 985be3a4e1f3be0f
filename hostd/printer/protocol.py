"""Marlin host protocol: line framing, checksums and parsing of the firmware's replies.

Pure functions only (no I/O), shared by the driver and the simulator.

Framing: ``N<n> <command>*<checksum>\\n`` where the checksum is the XOR of every byte
before ``*``. Replies we care about:

- ``ok`` / ``ok T:..`` / ``ok N12 P15 B3`` (ADVANCED_OK: line, planner free, buffer free)
- ``Resend: 12`` / ``rs 12`` (replay from line 12)
- ``Error:...`` (resend-related ones mention the checksum or line number)
- ``echo:busy: processing`` / ``wait`` (signs of life, *not* an ok)
- ``start`` (the board has just reset), ``FIRMWARE_NAME:..``, ``Cap:NAME:0|1``
- `` T:25.00 /0.00 B:24.90 /60.00 @:0 B@:0`` (temperature report, M105 or M155)
- ``//action:cancel`` (host action commands: the printer's own controls asking the
  host to ``cancel``, ``pause`` or ``resume``, or saying it ``paused``/``resumed`` itself;
  Prusa firmware writes ``// action:``)
"""

import re
from dataclasses import dataclass, field

# Reply kinds.
OK = "ok"
RESEND = "resend"
ERROR = "error"
BUSY = "busy"
START = "start"
TEMPS = "temps"
CAP = "cap"
FIRMWARE = "firmware"
ECHO = "echo"
ACTION = "action"
OTHER = "other"

_TEMP_RE = re.compile(r"(?<![A-Za-z@])([TBC]\d*)\s*:\s*(-?\d+(?:\.\d*)?)\s*(?:/\s*(-?\d+(?:\.\d*)?))?")
# "Resend:" may follow line noise; the short "rs" form only counts at the start.
_RESEND_RE = re.compile(r"(?:resend:|^rs[:\s])\s*N?\s*:?\s*(\d+)", re.IGNORECASE)
_OK_FIELD_RE = re.compile(r"\b([NPB])(\d+)\b")
_CAP_RE = re.compile(r"^Cap:([A-Z0-9_]+):\s*([01])")
_ACTION_RE = re.compile(r"^//\s*action:\s*(\w+)", re.IGNORECASE)

# Error messages from Marlin that are followed by a resend request (not fatal).
_RESEND_ERROR_WORDS = ("checksum", "line number", "last line", "expected line", "format error")


def checksum(data):
    """XOR of all bytes of ``data`` (bytes), as Marlin computes it."""
    value = 0
    for byte in data:
        value ^= byte
    return value


def clean(line):
    """Strip ``;`` comments and surrounding whitespace; return '' for nothing to send.

    Marlin would ignore the comment anyway, but sending it wastes link bandwidth and a
    ``*`` inside a comment would break the checksum framing.
    """
    cut = line.find(";")
    if cut >= 0:
        line = line[:cut]
    return line.strip()


def frame(number, command):
    """Return the wire bytes of ``command`` as line ``number`` with its checksum."""
    body = ("N%d %s" % (number, command)).encode("ascii", "replace")
    return body + b"*" + str(checksum(body)).encode("ascii") + b"\n"


def unframe(raw):
    """Split a received line into (number or None, command, checksum ok or None).

    Used by the simulator; ``checksum ok`` is None when the line carries no checksum.
    """
    text = raw.strip()
    number = None
    good = None
    star = text.rfind(b"*")
    if star >= 0:
        try:
            good = int(text[star + 1:].strip() or b"-1") == checksum(text[:star])
        except ValueError:
            good = False
        text = text[:star]
    if text[:1] in (b"N", b"n"):
        match = re.match(rb"[Nn]\s*(-?\d+)\s*", text)
        if match:
            number = int(match.group(1))
            text = text[match.end():]
    return number, text.decode("ascii", "replace").strip(), good


@dataclass
class Reply:
    """One parsed line from the firmware."""

    kind: str
    text: str
    line: int = None           # ok N.. (ADVANCED_OK) or the Resend: target
    planner_free: int = None   # ok .. P..
    buffer_free: int = None    # ok .. B..
    temps: dict = field(default_factory=dict)  # heater -> (current, target or None)
    cap: tuple = None          # (name, enabled) for Cap: lines
    action: str = None         # the name of a //action: line, lower case


def parse_temperatures(text):
    """Return {heater: (current, target or None)} from a Marlin temperature report.

    ``T`` is the active hotend, ``T0``/``T1`` the individual ones, ``B`` the bed, ``C`` the
    chamber; power fields (``@:``, ``B@:``) and ``W:`` are ignored.
    """
    temps = {}
    for name, current, target in _TEMP_RE.findall(text):
        try:
            temps[name] = (float(current), float(target) if target else None)
        except ValueError:
            continue
    return temps


_FRAGMENT_RE = re.compile(r'Unknown command:\s*"[\d\s]*"')


def is_fragment_echo(text):
    """True for Marlin's ``Unknown command: "07"``: the checksum digits of a line whose
    start was flushed after a line error (no command we send is only digits)."""
    return bool(_FRAGMENT_RE.search(text))


def is_resend_error(text):
    """True for ``Error:`` messages that Marlin follows with ``Resend:`` (not fatal)."""
    low = text.lower()
    return any(word in low for word in _RESEND_ERROR_WORDS)


def parse_reply(raw):
    """Parse one raw line (bytes) from the firmware into a :class:`Reply`.

    Garbage bytes and non-ASCII noise are tolerated: they are replaced, stripped of
    control characters and end up as kind ``other`` unless a known prefix survives.
    """
    text = raw.decode("ascii", "replace")
    text = "".join(ch for ch in text if ch >= " " or ch == "\t").strip()
    low = text.lower()
    if low.startswith("ok"):
        reply = Reply(OK, text)
        rest = text[2:]
        if "T:" in rest or "B:" in rest:
            reply.temps = parse_temperatures(rest)
        else:
            for key, value in _OK_FIELD_RE.findall(rest):
                if key == "N":
                    reply.line = int(value)
                elif key == "P":
                    reply.planner_free = int(value)
                else:
                    reply.buffer_free = int(value)
        return reply
    match = _RESEND_RE.search(text)
    if match:
        return Reply(RESEND, text, line=int(match.group(1)))
    if low.startswith("error"):
        return Reply(ERROR, text)  # kept verbatim: it is what the user must see
    if low.startswith("echo:busy") or low.startswith("busy:") or low == "wait":
        return Reply(BUSY, text)
    if low == "start":
        return Reply(START, text)
    match = _ACTION_RE.match(text)
    if match:
        return Reply(ACTION, text, action=match.group(1).lower())
    match = _CAP_RE.match(text)
    if match:
        return Reply(CAP, text, cap=(match.group(1), match.group(2) == "1"))
    if text.startswith("FIRMWARE_NAME"):
        return Reply(FIRMWARE, text)
    if "T:" in text or text.startswith("B:"):
        temps = parse_temperatures(text)
        if temps:
            return Reply(TEMPS, text, temps=temps)
    if low.startswith("echo:"):
        return Reply(ECHO, text)
    return Reply(OTHER, text)


def parse_firmware_info(text):
    """Parse ``FIRMWARE_NAME:Marlin 2.1 SOURCE_CODE_URL:... MACHINE_TYPE:...`` into a dict."""
    keys = re.findall(r"([A-Z_]{4,}):", text)
    info = {}
    for i, key in enumerate(keys):
        start = text.index(key + ":") + len(key) + 1
        end = text.index(keys[i + 1] + ":", start) if i + 1 < len(keys) else len(text)
        info[key] = text[start:end].strip()
    return info
