"""A Marlin-like firmware model: line checking, command queue, planner, heaters.

Pure logic driven by timestamps (no threads, no I/O): the simulator feeds it the bytes
that arrived on the wire (with their arrival time), calls :meth:`Firmware.step` and sends
:attr:`Firmware.out` back at the link's byte rate. Messages follow Marlin 2.x wording so a
host that copes with this copes with the real thing.

Marlin behaviours reproduced on purpose because hosts get them wrong:

- a line error flushes the whole receive buffer, then prints ``Resend: N`` and ``ok``;
  lines that were behind it in the buffer vanish silently, lines still on the wire each
  get their own error/resend/ok;
- lines are read from the receive buffer only while the command queue has room, so a
  full planner backs up into the queue and then the receive buffer (bytes arriving at a
  full receive buffer are dropped and counted as an overrun);
- ``ok`` is sent when a command has been processed (a move: entered into the planner),
  ``M105`` answers ``ok T:..`` without ADVANCED_OK fields;
- the emergency parser acts on ``M112`` the moment its newline arrives.
"""

import math
import re
from collections import deque

from hostd.printer import protocol

FIRMWARE_NAME = ("FIRMWARE_NAME:Marlin 2.1.2 (hostd-sim) SOURCE_CODE_URL:github.com/MarlinFirmware/Marlin "
                 "PROTOCOL_VERSION:1.0 MACHINE_TYPE:hostd simulated printer EXTRUDER_COUNT:1 "
                 "UUID:00000000-0000-4000-8000-000000000000")
RUNAWAY = "Error:Thermal Runaway, system stopped! Heater_ID: 0"
HALTED = "Error:Printer halted. kill() called!"
AMBIENT_C = 25.0
TEMP_WINDOW_C = 1.0
WAIT_REPORT_S = 1.0      # M109/M190 print temperatures once a second (real time)
MAX_CMD_SIZE = 96        # Marlin's MAX_CMD_SIZE: longer lines are truncated
_WORD_RE = re.compile(r"([A-Za-z])\s*([-+]?\d*\.?\d*)")
_LINE_END = re.compile(rb"[\r\n]")
_MOTION = ("G0", "G1", "G2", "G3")
_TRANSPARENT = ("M105", "M155", "M114", "M115", "M110")  # host housekeeping, not a job step
_KNOWN = {"G0", "G1", "G2", "G3", "G4", "G21", "G28", "G90", "G91", "G92", "M17", "M18", "M82",
          "M83", "M84", "M104", "M105", "M106", "M107", "M108", "M109", "M110", "M112", "M114",
          "M115", "M117", "M140", "M155", "M190", "M201", "M203", "M204", "M205", "M220",
          "M221", "M400", "M410", "M900", "T0"}


def words(command):
    """Split ``G1 X1.5 F600`` into ('G1', {'X': 1.5, 'F': 600.0}).

    Like Marlin's parser the command letter must come first: ``45 G1 X1`` (the tail of a
    line cut in two) is not a G1 but an unknown command, code ''.
    """
    text = command.split(";")[0].lstrip()
    if not text[:1].isalpha():
        return "", {}
    pairs = _WORD_RE.findall(text)
    if not pairs:
        return "", {}
    code = pairs[0][0].upper() + pairs[0][1].lstrip("+").split(".")[0].lstrip("0") or "0"
    if code[1:] == "":
        code += "0"
    params = {}
    for letter, value in pairs[1:]:
        try:
            params[letter.upper()] = float(value) if value not in ("", "-", "+", ".") else None
        except ValueError:
            params[letter.upper()] = None
    return code, params


class Heater:
    """First-order heater: approaches its target (or ambient when off) exponentially."""

    def __init__(self, tau_s):
        self.tau_s = tau_s
        self.current = AMBIENT_C
        self.target = 0.0

    def advance(self, dt_s, time_scale):
        goal = self.target if self.target > 0 else AMBIENT_C
        if time_scale <= 0 or self.tau_s <= 0:
            self.current = goal
            return
        self.current = goal + (self.current - goal) * math.exp(-dt_s / (self.tau_s * time_scale))

    def reached(self):
        return abs(self.current - self.target) <= TEMP_WINDOW_C or self.target <= 0


class Firmware:
    """Marlin-like firmware state machine (see module docstring)."""

    def __init__(self, config, rng):
        self.config = config
        self.rng = rng
        self.executed = []          # every command executed, in order: (line number, text)
        self.out = []               # reply lines waiting to be sent (without newline)
        self.fault = None           # 'reset' / 'disconnect' for the simulator to act on
        self.stats = dict(lines_received=0, line_errors=0, rx_overruns=0, lost_oks=0,
                          corrupted=0, unknown_commands=0, max_queue=0, max_unacked=0, starvation_s=0.0,
                          starvation_events=0, max_starvation_gap_s=0.0, moves=0,
                          emergency_stop_at=None, killed=None)
        self._fired = set()
        self.reset(0.0)

    # -- lifecycle ---------------------------------------------------------------------

    def reset(self, now):
        """Power-on state (the board resets whenever the port is opened)."""
        self.rx = bytearray()
        self.rx_times = deque()      # arrival time of each complete line in rx
        self.ring = deque()          # command queue: [number, text, arrival time]
        self.current_state = None    # per-command scratch while a command blocks
        self.planner = deque()       # [start, end] of each planned move
        self.planner_empty_since = now
        self.last_pop_time = now
        self.last_done_time = now
        self.last_exec_was_move = False
        self.last_n = 0
        self.halted = False
        self.unacked = 0             # lines accepted but not yet answered with ok
        self.hotend = Heater(self.config.hotend_tau_s)
        self.bed = Heater(self.config.bed_tau_s)
        self.heat_time = now
        self.autoreport_s = 0.0
        self.next_autoreport = None
        self.next_busy = None
        self.next_wait_report = None
        self.position = dict(X=0.0, Y=0.0, Z=0.0, E=0.0)
        self.relative = False
        self.relative_e = False
        self.feed_mm_min = 1500.0
        self.feed_percent = 100.0
        self._ep_line = bytearray()

    def banner(self):
        self.out += ["start", "echo:Marlin 2.1.2 (hostd-sim)", "echo: Last Updated: 2026-01-01",
                     "echo:Free Memory: 4096  PlannerBufferBytes: 1024", "echo:SD card ok"]

    # -- input -------------------------------------------------------------------------

    def feed(self, data, now):
        """Bytes arrive from the wire at time ``now`` into the receive buffer.

        Taken a run up to each line end at a time: byte by byte, with a call each, they were
        a quarter of the simulated firmware's time."""
        if self.halted:
            return
        data = bytes(data)
        start, size = 0, len(data)
        while start < size:
            found = _LINE_END.search(data, start)
            end = found.start() if found else size
            if end > start:
                run = data[start:end]
                if self.config.emergency_parser and len(self._ep_line) < 32:
                    self._ep_line += run[:32 - len(self._ep_line)]
                room = max(0, self.config.rx_bytes - len(self.rx))
                self.rx += run[:room]
                self.stats["rx_overruns"] += max(0, len(run) - room)
            if found is None:
                return
            if self.config.emergency_parser:
                self._emergency_parse(now)
                if self.halted:
                    return
            if len(self.rx) >= self.config.rx_bytes:
                self.stats["rx_overruns"] += 1
            else:
                self.rx.append(data[end])
                self.rx_times.append(now)
            start = end + 1

    def _emergency_parse(self, now):
        """A line end arrived: act on the line before it if it is an emergency command."""
        number, text, _ = protocol.unframe(bytes(self._ep_line))
        self._ep_line.clear()
        code = text.strip().upper()
        if code == "M112":
            self.stats["emergency_stop_at"] = now
            self._kill(now, "M112")
        elif code == "M108" and self.current_state is not None:
            self.current_state["cancel_wait"] = True
        elif code == "M410":
            self.planner.clear()

    def _kill(self, now, why):
        self.out.append(HALTED)
        self.halted = True
        self.stats["killed"] = (now, why)
        self.planner.clear()
        self.ring.clear()
        self.rx.clear()
        self.hotend.target = self.bed.target = 0.0

    # -- main loop ---------------------------------------------------------------------

    def step(self, now):
        """Advance the firmware to time ``now``: read lines, run commands, report."""
        if self.halted:
            return
        self._advance_heaters(now)
        self._advance_planner(now)
        progress = True
        while progress and not self.halted and self.fault is None:
            progress = self._read_lines()
            if self.ring and self._run_head(now):
                progress = True
        self._reports(now)

    def next_wakeup(self, now):
        """When :meth:`step` should run next without new input (None = nothing to do)."""
        if self.halted:
            return None
        times = [t for t in (self.next_autoreport, self.next_busy, self.next_wait_report) if t]
        state = self.current_state or {}
        if self.ring:
            if self.planner:
                times.append(self.planner[0][1])
            if "until" in state:
                times.append(state["until"])
            if state.get("heating"):
                times.append(now + 0.02)
        return min(times) if times else None

    def _read_lines(self):
        """Move complete lines from the receive buffer into the command queue."""
        moved = False
        while len(self.ring) < self.config.bufsize and self.rx_times:
            cut = min(i for i in (self.rx.find(b"\n"), self.rx.find(b"\r")) if i >= 0)
            raw = bytes(self.rx[:cut])
            del self.rx[:cut + 1]
            arrival = self.rx_times.popleft()
            moved = True
            self._accept(raw[:MAX_CMD_SIZE], arrival)
        return moved

    def _accept(self, raw, arrival):
        raw = raw.split(b";")[0].strip()
        if not raw:
            return
        self.stats["lines_received"] += 1
        if self.config.fault_corrupt and self.rng.random() < self.config.fault_corrupt:
            raw = self._corrupt(raw)
        number, text, good = protocol.unframe(raw)
        if number is not None:
            is_m110 = "M110" in text.upper()
            if is_m110:
                code, params = words(text)
                if params.get("N") is not None:
                    number = int(params["N"])
            if number != self.last_n + 1 and not is_m110:
                return self._line_error("Line Number is not Last Line Number+1")
            if good is None:
                return self._line_error("No Checksum with line number")
            if not good:
                return self._line_error("checksum mismatch")
            self.last_n = number
        elif good is not None:
            return self._line_error("No Line Number with checksum")
        self.ring.append([number, text, arrival])
        self.stats["max_queue"] = max(self.stats["max_queue"], len(self.ring))
        self.unacked += 1
        self.stats["max_unacked"] = max(self.stats["max_unacked"], self.unacked)

    def _corrupt(self, raw):
        """Flip one bit of one byte, never creating a line end (the wire stays framed)."""
        self.stats["corrupted"] += 1
        data = bytearray(raw)
        i = self.rng.randrange(len(data))
        for bit in self.rng.sample(range(7), 7):
            flipped = data[i] ^ (1 << bit)
            if flipped not in (10, 13, 0, ord(";")) and flipped != data[i]:
                data[i] = flipped
                break
        return bytes(data)

    def _line_error(self, message):
        self.stats["line_errors"] += 1
        self.out.append("Error:%s, Last Line: %d" % (message, self.last_n))
        # Marlin empties the receive buffer after a line error: everything behind the
        # bad line is lost without a word, which is why hosts must resend from N.
        self.rx.clear()
        self.rx_times.clear()
        self.out.append("Resend: %d" % (self.last_n + 1))
        self.out.append("ok")

    def _run_head(self, now):
        """Run the command at the head of the queue; True when it completed."""
        number, text, arrival = self.ring[0]
        if self.current_state is None:
            if self._line_faults(number, now):
                return False
            self.current_state = {}
        code, params = words(text)
        if not self.current_state:
            if code[:1] in ("G", "M", "T"):
                self.executed.append((number, text))
            else:
                # E.g. the checksum digits left of a line cut in half by the flush after a
                # line error: Marlin answers "Unknown command" and ok, and does nothing.
                self.stats["unknown_commands"] += 1
            self.current_state["seen"] = True
        # Simulated time of this step: when the line arrived, a planner slot freed or the
        # previous command finished -- not when this thread got round to it.
        t_in = max(arrival, self.last_pop_time, self.last_done_time)
        result = self._execute(code, params, text, t_in, now)
        if result is False:
            self._keepalive(now)
            return False
        self.last_done_time = t_in if code in _MOTION else now
        self.ring.popleft()
        self.current_state = None
        self.next_busy = None
        self.next_wait_report = None
        if code not in _TRANSPARENT:
            self.last_exec_was_move = code in _MOTION
        self.unacked -= 1
        if result == "ok":
            self._ok(number)
        return True

    def _line_faults(self, number, now):
        config = self.config
        for name, line in (("runaway", config.fault_runaway_line), ("reset", config.fault_reset_line),
                           ("disconnect", config.fault_disconnect_line),
                           ("stall", config.fault_stall_line)):
            if line and number == line and name not in self._fired:
                self._fired.add(name)
                if name == "runaway":
                    self.out.append(RUNAWAY)
                    self._kill(now, "thermal runaway")
                else:
                    self.fault = name
                return True
        return False

    def _ok(self, number):
        if self.config.fault_lost_ok and self.rng.random() < self.config.fault_lost_ok:
            self.stats["lost_oks"] += 1
            return
        if not self.config.advanced_ok:
            self.out.append("ok")
            return
        line = " N%d" % number if number is not None else ""
        free_planner = self.config.planner - len(self.planner)
        # The finished command still occupies its slot when Marlin prints the ok.
        free_buffer = self.config.bufsize - len(self.ring) - 1
        self.out.append("ok%s P%d B%d" % (line, free_planner, free_buffer))

    def _keepalive(self, now):
        if self.next_busy is None:
            self.next_busy = now + self.config.keepalive_s
        elif now >= self.next_busy:
            self.out.append("echo:busy: processing")
            self.next_busy = now + self.config.keepalive_s

    # -- commands ----------------------------------------------------------------------

    def _execute(self, code, params, text, t_in, now):
        """Return 'ok' (done, send ok), 'quiet' (done, already answered) or False (blocked)."""
        state = self.current_state
        if code in _MOTION:
            return self._move(params, t_in)
        if code in ("G4", "G28", "M400"):
            if self.planner:
                return False
            if "until" not in state:
                if code == "G4":
                    dwell_s = (params.get("P") or 0) / 1000.0 + (params.get("S") or 0)
                else:
                    dwell_s = 1.0 if code == "G28" else 0.0
                state["until"] = now + dwell_s * self.config.time_scale
                if code == "G28":
                    self.position.update(X=0.0, Y=0.0, Z=0.0)
            return "ok" if now >= state["until"] else False
        if code in ("M104", "M109"):
            return self._heat(self.hotend, code == "M109", params, now)
        if code in ("M140", "M190"):
            return self._heat(self.bed, code == "M190", params, now)
        if code == "M105":
            self.out.append("ok " + self.temperature_text())
            return "quiet"
        if code == "M155":
            self.autoreport_s = params.get("S") or 0
            self.next_autoreport = now + self.autoreport_s if self.autoreport_s else None
        elif code == "M115":
            self.out.append(FIRMWARE_NAME)
            caps = dict(SERIAL_XON_XOFF=0, EEPROM=0, AUTOREPORT_TEMP=int(self.config.autoreport),
                        EMERGENCY_PARSER=int(self.config.emergency_parser),
                        ADVANCED_OK=int(self.config.advanced_ok), HOST_ACTION_COMMANDS=0,
                        PROMPT_SUPPORT=0, EXTENDED_M20=0)
            self.out += ["Cap:%s:%d" % item for item in caps.items()]
        elif code == "M112":
            self._kill(now, "M112")
            return "quiet"
        elif code == "M410":
            self.planner.clear()
        elif code == "M114":
            p = self.position
            self.out.append("X:%.2f Y:%.2f Z:%.2f E:%.2f Count X:0 Y:0 Z:0" % (p["X"], p["Y"], p["Z"], p["E"]))
        elif code == "M220" and params.get("S"):
            self.feed_percent = params["S"]
        elif code in ("G90", "G91"):
            self.relative = self.relative_e = code == "G91"
        elif code in ("M82", "M83"):
            self.relative_e = code == "M83"
        elif code == "G92":
            for axis in self.position:
                if params.get(axis) is not None:
                    self.position[axis] = params[axis]
        elif code not in _KNOWN:
            self.out.append('echo:Unknown command: "%s"' % text)
        return "ok"

    def _move(self, params, t_in):
        if len(self.planner) >= self.config.planner:
            return False
        if params.get("F"):
            self.feed_mm_min = params["F"]
        delta = {}
        for axis in self.position:
            value = params.get(axis)
            if value is None:
                continue
            relative = self.relative_e if axis == "E" else self.relative
            target = self.position[axis] + value if relative else value
            delta[axis] = target - self.position[axis]
            self.position[axis] = target
        length = math.sqrt(sum(delta.get(a, 0.0) ** 2 for a in "XYZ")) or abs(delta.get("E", 0.0))
        feed_mm_s = self.feed_mm_min / 60.0 * self.feed_percent / 100.0
        duration_s = length / feed_mm_s * self.config.time_scale if feed_mm_s > 0 else 0.0
        if self.planner:
            start = max(self.planner[-1][1], t_in)
        else:
            start = t_in
            gap = t_in - self.planner_empty_since
            if self.last_exec_was_move and gap > 0:
                # The planner ran dry between two moves: the host did not keep up.
                self.stats["starvation_s"] += gap
                self.stats["starvation_events"] += 1
                self.stats["max_starvation_gap_s"] = max(self.stats["max_starvation_gap_s"], gap)
        self.planner.append([start, start + duration_s])
        self.stats["moves"] += 1
        return "ok"

    def _heat(self, heater, wait, params, now):
        state = self.current_state
        target = params.get("S") if params.get("S") is not None else params.get("R")
        if "target" not in state:
            state["target"] = target
            if target is not None:
                heater.target = target
        if not wait or heater.target <= 0:
            return "ok"
        state["heating"] = True
        if heater.reached() or state.get("cancel_wait"):
            return "ok"
        if self.next_wait_report is None:
            self.next_wait_report = now + WAIT_REPORT_S
        elif now >= self.next_wait_report:
            self.out.append(self.temperature_text() + " W:?")
            self.next_wait_report = now + WAIT_REPORT_S
        return False

    # -- time --------------------------------------------------------------------------

    def _advance_planner(self, now):
        while self.planner and self.planner[0][1] <= now:
            self.planner_empty_since = self.last_pop_time = self.planner.popleft()[1]

    def _advance_heaters(self, now):
        dt_s = now - self.heat_time
        self.heat_time = now
        if dt_s > 0:
            self.hotend.advance(dt_s, self.config.time_scale)
            self.bed.advance(dt_s, self.config.time_scale)

    def _reports(self, now):
        if self.next_autoreport and now >= self.next_autoreport:
            self.out.append(" " + self.temperature_text())
            self.next_autoreport = now + self.autoreport_s

    def temperature_text(self):
        h, b = self.hotend, self.bed
        return "T:%.2f /%.2f B:%.2f /%.2f @:%d B@:%d" % (
            h.current, h.target, b.current, b.target, 127 if h.target else 0, 127 if b.target else 0)
