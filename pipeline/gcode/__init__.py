"""G-code: thickness-varying layers from the tool paths (``writer``), with arcs, compact number
text and the print-time estimate."""
