"""Numbered lines in flight: resend history, flow-control window, answer bookkeeping.

Used only by the driver thread. The rules, all following from Marlin accepting line N
only right after N-1 (so the firmware itself never runs a line twice):

- every transmission waits in ``fifo`` for its answer; an ``ok`` answers the oldest one,
  an ``ok N<n>`` (ADVANCED_OK) answers everything up to line n (older oks were lost);
- ``Resend: r`` is always followed by a plain ``ok`` that answers the rejected line, not
  a processed one (``error_acks``); lines before r were accepted and keep waiting for
  their own ok, lines from r on are dropped or rejected by the firmware, so sending
  restarts at r once the link has been quiet for a moment;
- every line that was behind r and escaped the flush provokes another ``Resend: r``: an
  echo, not a new request (at most one per line dropped from the window). An echo can
  come after the replay went out (the firmware was slow to read, or its answer slow to
  arrive); its own flush may or may not have taken the replay with it, so the replay
  goes again after a quiet unless answered meanwhile -- and an ``ok N<n>`` counts for
  line n by its number, whichever transmission of n it answers;
- the flush can cut a line in two; the tail is only checksum digits (anything else
  would contain the ``*``), which Marlin answers with ``Unknown command`` and an ok
  that answers nothing;
- after a silent timeout the unanswered lines go to ``limbo``: the next answered line
  (or resend request) tells which of them the firmware had accepted.
"""

from collections import OrderedDict, deque
from dataclasses import dataclass

from hostd.printer import protocol
from hostd.printer.errors import PrinterError


@dataclass
class Sent:
    """One numbered line: its wire bytes and where it came from."""

    n: int
    data: bytes
    command: str
    origin: tuple    # ("job", file line) / ("script", name) / ("poll",) / ("probe",) / ("user",) / ("host",)


class LineFlow:
    """Line numbering, history and the in-flight window of one connection."""

    def __init__(self, settings, stats, byte_s):
        self.settings = settings
        self.stats = stats
        self.byte_s = byte_s
        self.reset()

    def reset(self, next_n=1, capacity=1):
        self.history = OrderedDict()
        self.next_n = next_n          # number of the next new line
        self.cursor = next_n          # next number to transmit (< next_n while replaying)
        self.capacity = capacity      # lines in flight allowed (1 = ping-pong)
        self.fifo = deque()           # transmissions waiting for an answer
        self.fifo_bytes = 0
        self.limbo = []               # unanswered when a timeout struck
        self.error_acks = 0           # oks still due for resend requests
        self.resync_target = None
        self.resync_until = 0.0
        self.echoes_due = 0           # lines behind resync_target that may still echo it
        self.last_confirmed_n = -1    # highest line the firmware answered with a real ok

    # -- state ---------------------------------------------------------------------------

    def remember(self, sent):
        """Record a line sent outside the window (handshake) so it can be resent."""
        self.history[sent.n] = sent

    def awaiting(self):
        """True while some answer is due."""
        return bool(self.fifo or self.error_acks)

    def settled(self):
        """Everything sent has been answered and nothing is left to replay."""
        return not self.fifo and not self.limbo and self.cursor >= self.next_n and not self.error_acks

    def head_command(self):
        return self.fifo[0].command if self.fifo else ""

    def abandon(self):
        """Stop waiting for answers and replays (the firmware is halted)."""
        self.fifo.clear()
        self.fifo_bytes = 0
        self.limbo = []
        self.error_acks = 0
        self.cursor = self.next_n
        self.resync_until = 0.0
        self.echoes_due = 0

    # -- sending -------------------------------------------------------------------------

    def replaying(self):
        return self.cursor < self.next_n

    def window_full(self, now):
        """No transmission allowed now (resync pause, window, or an ok still due)."""
        if now < self.resync_until:
            return True
        return bool(self.fifo) and (len(self.fifo) >= self.capacity or self.error_acks > 0)

    def fits(self, sent):
        """The firmware's receive buffer can take ``sent`` on top of what is in flight."""
        return not self.fifo or self.fifo_bytes + len(sent.data) <= self.settings.rx_buffer_bytes

    def replay_line(self):
        return self.history[self.cursor]

    def new_line(self, command, origin):
        """Frame ``command`` as the next new line (not committed until :meth:`commit`)."""
        return Sent(self.next_n, protocol.frame(self.next_n, command), command, origin)

    def commit(self, sent, new):
        """``sent`` is being written: it now waits for an answer."""
        if new:
            self.history[sent.n] = sent
            if len(self.history) > self.settings.history_lines:
                self.history.popitem(last=False)
            self.next_n = sent.n + 1
        else:
            self.stats["lines_resent"] += 1
        self.cursor = sent.n + 1
        self.fifo.append(sent)
        self.fifo_bytes += len(sent.data)
        stats = self.stats
        stats["lines_sent"] += 1
        stats["bytes_sent"] += len(sent.data)
        stats["max_in_flight_lines"] = max(stats["max_in_flight_lines"], len(self.fifo))
        stats["max_in_flight_bytes"] = max(stats["max_in_flight_bytes"], self.fifo_bytes)

    # -- answers -------------------------------------------------------------------------

    def on_ok(self, line, unnumbered=False):
        """An ok; return the Sent lines it confirms (None: it answers nothing of ours).

        ``line`` is the ADVANCED_OK ``N``; ``unnumbered`` marks an ADVANCED_OK answer
        without ``N``: the firmware ran a line without number (our M108, or the tail of
        a line cut by its flush), which is not in our books.
        """
        self.stats["oks"] += 1
        if unnumbered:
            self.stats["unnumbered_oks"] = self.stats.get("unnumbered_oks", 0) + 1
            return None
        if self.error_acks:
            self.error_acks -= 1   # the ok that follows a Resend: nothing was executed
            return None
        confirmed = []
        answered = None
        if line is not None:
            if any(s.n == line for s in self.fifo):
                while self.fifo:
                    answered = self._pop()
                    confirmed.append(answered)
                    if answered.n == line:
                        break
            elif any(s.n == line for s in self.limbo):
                answered = next(s for s in self.limbo if s.n == line)
                self.limbo.remove(answered)
                confirmed.append(answered)
            elif self.last_confirmed_n < line < self.next_n and line in self.history:
                # Its transmission was dropped from the window at a late echo, but the
                # flush had missed it: the firmware has it and every line before it.
                while self.fifo and self.fifo[0].n < line:
                    self._pop()
                self.limbo = [s for s in self.limbo if s.n > line]
                confirmed = [self.history[n] for n in range(self.last_confirmed_n + 1, line + 1)
                             if n in self.history]
                answered = confirmed[-1]
            # else: an answer for a line already resolved.
        elif self.fifo:
            answered = self._pop()
            confirmed.append(answered)
        elif self.limbo:
            answered = self.limbo.pop(0)    # a late answer after a timeout
            confirmed.append(answered)
        if answered is not None and self.limbo:
            # The firmware took line n only after n-1: everything older was accepted.
            confirmed += [s for s in self.limbo if s.n < answered.n]
            self.limbo = [s for s in self.limbo if s.n > answered.n]
        if answered is not None and self.cursor <= answered.n:
            self.cursor = answered.n + 1     # no replaying what the firmware already has
        if confirmed:
            self.last_confirmed_n = max(self.last_confirmed_n, max(s.n for s in confirmed))
            if self.resync_target is not None and self.last_confirmed_n >= self.resync_target:
                self.echoes_due = 0   # the replay was read, so were all the stragglers before it
        return confirmed

    def on_resend(self, line, now):
        """A resend request; return (lines now known accepted, honoured: bool)."""
        self.error_acks += 1
        if line not in self.history and line != self.next_n:
            raise PrinterError("resend", "firmware asked for line %d which is no longer in history" % line)
        accepted = [s for s in self.limbo if s.n < line]
        self.limbo = []
        echo = (line == self.resync_target and line > self.last_confirmed_n
                and (now < self.resync_until or self.echoes_due > 0))
        if echo:
            self.echoes_due = max(0, self.echoes_due - 1)
        elif line <= self.last_confirmed_n:
            # An ok we took for that line belonged to something else (a reply lost to
            # line noise). The firmware's own N == last+1 rule still guarantees it runs
            # the line once, so replaying is right; the miscount is only recorded.
            self.stats["misattributed_oks"] = self.stats.get("misattributed_oks", 0) + 1
            self.last_confirmed_n = line - 1
        kept = deque(s for s in self.fifo if s.n < line)
        doomed = len(self.fifo) - len(kept)
        self.fifo = kept
        self.fifo_bytes = sum(len(s.data) for s in kept)
        self.cursor = line
        if echo:
            # Nothing sent since the request, or a replay that went out behind the
            # straggler and may have gone with its flush: (again) after a quiet.
            self.resync_until = now + self.quiet_s()
            return accepted, False
        self.stats["resends"] += 1
        self.resync_target = line
        # One transmission drew this request; each other one drops out in the flush
        # or answers it once more.
        self.echoes_due = max(0, doomed - 1)
        # Only wait for stragglers when more than the offending line was in flight.
        self.resync_until = now + self.quiet_s() if doomed > 1 else now
        return accepted, True

    def on_line_error(self, now):
        """An ``Error:`` about checksum/line number: more echoes may follow, stay quiet."""
        if self.resync_until > now:
            self.resync_until = now + self.quiet_s()

    def expect_foreign_ok(self):
        """An ok is coming that answers nothing we track: the firmware ran the digits left
        of a line cut by its flush ("Unknown command"), or our unnumbered M108."""
        self.error_acks += 1

    def quiet_s(self):
        return max(self.settings.resend_quiet_s, 3 * self.settings.rx_buffer_bytes * self.byte_s)

    def expire(self):
        """Answer timeout: whatever was in flight lost its answer (see module docstring)."""
        self.limbo += list(self.fifo)
        self.fifo.clear()
        self.fifo_bytes = 0
        self.error_acks = 0
        self.echoes_due = 0   # long read by now: a request after the probe is a real one

    def _pop(self):
        sent = self.fifo.popleft()
        self.fifo_bytes -= len(sent.data)
        return sent
