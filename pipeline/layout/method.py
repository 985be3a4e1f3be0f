"""The layout methods, found by name: ``isoline`` (the paper's) and ``free``.

Each is one object with the same small interface, so the plan runs the stages and the
looks at a plan the gate turned down without naming the method:

- ``name``; ``other``: the other method's name; ``title``: how a note names it;
- ``prepare(result, hf, profile, sidecar, opts, stage, timing, force_fit)`` -> the
  HeightField to plan (free: fitted to what forms; isoline: ``hf``);
- ``sheet(result, hf, profile, path, stage, timing, opts)``: mesh, layout, simulation
  and tool paths, filling ``result`` (``mesh``, ``flat``, ``sim``, ``xy_bed``,
  ``toolpaths``, ...);
- ``after(result, hf, profile, sidecar, opts, timing)``: what the method checks once
  its sheet is simulated (free: a height asked for that does not form);
- ``would(hf, profile)`` -> the quick look at whether it would form ``hf`` (the
  report's ``other_method`` of a plan by the other method);
- ``hold_look``: whether a sheet too far from the shape is looked at for the smoothing
  at which it holds (:func:`pipeline.alternatives.smoothing_that_holds`).

``stage(name, message)`` opens a stage and returns its start time; ``timing`` maps
stage -> seconds.
"""

from pipeline.layout.free_method import FREE
from pipeline.layout.isoline_method import ISOLINE

METHODS = {m.name: m for m in (ISOLINE, FREE)}


def method_for(name):
    """The layout method called ``name`` (``"isoline"`` or ``"free"``)."""
    try:
        return METHODS[name]
    except KeyError:
        raise ValueError("no layout method %r (the methods: %s)"
                         % (name, ", ".join(sorted(METHODS)))) from None
