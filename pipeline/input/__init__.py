"""Input: read a height field and its sidecar, validate it as one printable sheet, simplify its
topology to what a sheet can form; and the synthetic reference shapes."""
