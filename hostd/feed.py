"""The feed rate a job prints at on one printer: slower only when its link cannot keep up.

The plan's report gives the file's moves per second at full feed and its mean line
length; the printer's own baud (which may differ from the profile's) gives what the link
carries. A printer starved of moves stops between them and blobs, so a job whose moves
would take more than :data:`pipeline.gcode.link.LINK_SHARE` of the link runs at a lower
feed percentage (M220) instead.
"""

from dataclasses import dataclass
from pathlib import Path

from hostd.reports import report_in
from pipeline.gcode.link import LINK_SHARE, feed_percent, link_moves_per_s


@dataclass(frozen=True)
class Feed:
    percent: int
    note: str             # why it is slowed, for the job's message ("" at full speed)

    @property
    def commands(self):
        """Sent before the file: every job sets its feed, so a slowed job's never lingers."""
        return ["M220 S%d" % self.percent]


def job_feed(gcode_path, baud):
    """The :class:`Feed` for printing ``gcode_path`` (with its ``NAME.report.json`` beside
    it) over a link at ``baud``; full speed when the report is missing or has no figures."""
    figures = _gcode_figures(Path(gcode_path))
    try:
        moves = float(figures["moves_per_s"])
        capacity = link_moves_per_s(baud, float(figures["bytes"]), float(figures["lines"]))
    except (KeyError, TypeError, ValueError):
        return Feed(100, "")
    pct = feed_percent(moves, capacity)
    if pct >= 100:
        return Feed(100, "")
    return Feed(pct, "feed slowed to %d %%: the file asks %.0f moves/s at full feed and "
                     "the link at %d baud carries %.0f lines/s (a print may use %d %% of it)"
                % (pct, moves, baud, capacity, round(100 * LINK_SHARE)))


def _gcode_figures(gcode_path):
    return report_in(gcode_path.parent).get("gcode") or {}
