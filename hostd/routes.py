"""Which printers a job may go to: a subfolder of the drop folder names a printer or a
profile, a sidecar may name a profile, and a job prints only on a printer of its profile."""


class Routes:
    """The routing rules of one node's printers (``slots``: :class:`hostd.slot.Slot`)."""

    def __init__(self, node_id, slots):
        self.node_id = node_id
        self.slots = slots

    def target_ok(self, target):
        """A drop subfolder (or None, the top) that names a printer or profile here."""
        return target is None or any(target in (s.name, s.config.profile) for s in self.slots)

    def profile_for(self, target, sidecar):
        """The profile a file is planned with: its sidecar's, its folder's, else the first
        printer's."""
        if sidecar is not None and sidecar.profile:
            return sidecar.profile
        for slot in self.slots:
            if target in (slot.name, slot.config.profile):
                return slot.config.profile
        return self.slots[0].config.profile

    def eligible(self, slot, job):
        """``job`` may print on ``slot``: its folder allows it and the profile matches."""
        t = job["target"]
        return (t is None or t in (slot.name, slot.config.profile)) \
            and slot.config.profile == job["profile"]

    def why_not(self, job):
        """None when a printer here can print ``job``, else why not (for its failure)."""
        if any(self.eligible(s, job) for s in self.slots):
            return None
        return self.no_printer_text(job["profile"], job["target"])

    def no_printer_text(self, profile, target):
        return ("No printer on node %s uses profile %r%s. Drop the file into a folder named "
                "after a printer or profile, or change the sidecar's `profile:`."
                % (self.node_id, profile, " in folder %r" % target if target else ""))
