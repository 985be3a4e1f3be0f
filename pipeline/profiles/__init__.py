"""Printer profiles: the YAML schema (``profile``), its canonical dump and hash (``dump``), the
thickness <-> shrink curve (``shrink``) and the calibration that measures it (``calibration``)."""
