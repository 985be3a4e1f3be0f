"""How many G-code lines a serial link carries per second, and the feed a file may run at.

A printer fed over a serial link can only execute the moves the link delivers: when a
file asks for more moves per second than the link carries, the firmware's planner runs
dry between moves and the nozzle stands still, extruding, for a moment (blobs and
zits). Each line travels framed as ``N<n> <command>*<checksum>\\n``; a byte costs ten
bits (start, eight data, stop).
"""

import math

# The share of the link a print may use: the host also sends temperature polls and
# resends, and the firmware's answers share its time.
LINK_SHARE = 0.8
# Mean digits of a checksum: the XOR of ASCII bytes is 0..127, so
# (10 * 1 + 90 * 2 + 28 * 3) / 128.
_CHECKSUM_DIGITS = 2.14


def framing_bytes(lines):
    """Mean bytes the host adds to each of ``lines`` numbered lines: ``N``, the number, a
    space and ``*`` with the checksum."""
    lines = max(int(lines), 1)
    digits = 0
    lo = 1
    while lo <= lines:
        hi = min(lines, lo * 10 - 1)
        digits += (hi - lo + 1) * len(str(lo))
        lo *= 10
    return 3 + digits / lines + _CHECKSUM_DIGITS


def link_moves_per_s(baud, file_bytes, file_lines):
    """Lines per second the link carries for a file of that mean line length (each line
    of a G-code file is at most one move)."""
    if baud <= 0 or file_lines <= 0:
        return math.inf
    line = file_bytes / file_lines + framing_bytes(file_lines)
    return baud / 10.0 / line


def feed_percent(moves_per_s, capacity_moves_per_s):
    """The feed rate percentage (M220) at which the file's moves fit in ``LINK_SHARE`` of
    the link: 100 when they already do, else rounded down to a whole per cent."""
    budget = LINK_SHARE * capacity_moves_per_s
    if moves_per_s <= budget or moves_per_s <= 0:
        return 100
    return max(1, int(math.floor(100.0 * budget / moves_per_s)))
