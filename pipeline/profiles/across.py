"""Calibration of the layers across: how far a strip curls when only its second and
second-last layer differ.

The plan's layers across the paths (:func:`pipeline.layout.laminate.across_layers`)
curl the sheet from inside the stack, on paths of their own; the bilayer strips, whose
lower and upper halves differ, do not measure them. These strips print those two
layers along their 60 mm side and every other layer across it (along the 10 mm side)
at the middle thickness of the range: those shrink only the strip's width, as much
above its middle as below, and curl nothing along it. The second layer prints thinner
(shrinks more) and the second-last thicker by a difference per strip, so by the
laminate (:class:`pipeline.layout.laminate.Laminate`) the strip curls along its length
by ``kappa = (c_across / 1.5) * 6 (N - 3) / (N^2 h) * (s_2 - s_{N-1})``, that is
``c_across * lever(N) * (s_2 - s_{N-1}) / h``. The measurement (rise over a chord),
the CSV and the fit are the bilayer strips' (:mod:`pipeline.profiles.bilayer`) with
that lever; the fitted constant becomes the profile's ``curvature.across_c``.
"""

import dataclasses

import numpy as np

from pipeline.layout.laminate import across_layers, curvature_per_lever, levers
from pipeline.profiles import bilayer
from pipeline.profiles.calibration import CalibrationError, rectangle_trace, specimen_label

LENGTH_MM, WIDTH_MM, COLUMNS = bilayer.LENGTH_MM, bilayer.WIDTH_MM, bilayer.COLUMNS


def layer_numbers(layers):
    """The two layers that print along the strips (from 1): the plan's layers across."""
    if layers < 4:
        raise CalibrationError(
            "the layers across need four layers or more; the profile prints %d" % layers,
            code="calibration.layers",
            fix="calibrate the layers across with a profile of four layers or more")
    return [int(k) + 1 for k in np.flatnonzero(across_layers(layers))]


def lever(layers):
    """How far a shrink difference between the layers across curls a strip, against a
    bilayer of the same difference and constant: ``4 (N - 3) / N^2`` (a third for six
    layers), read off the laminate's own levers."""
    below = layer_numbers(layers)[0] - 1
    # kappa = curvature_per_lever(h, N, c) * lever_2 * (s_2 - s_{N-1}) (lever_{N-1} is
    # -lever_2) and the bilayer's c / h: their ratio is independent of h and c.
    return float(curvature_per_lever(1.0, layers, 1.0) * levers(layers)[below])


def thickness_pairs(shrink, layers, thickness_min_mm, thickness_max_mm, n=5, c=1.5):
    """(layer 2, layer N-1) thicknesses as :func:`pipeline.profiles.bilayer.thickness_pairs`
    picks them, for the smaller lever of two layers: (n, 2) mm."""
    return bilayer.thickness_pairs(shrink, layers, thickness_min_mm, thickness_max_mm, n=n,
                                   c=c, lever=lever(layers))


def transverse_trace(specimen, path_width_mm):
    """A boustrophedon filling the specimen with paths across it (along its width)."""
    turned = dataclasses.replace(specimen, length_mm=specimen.width_mm,
                                 width_mm=specimen.length_mm,
                                 along="y" if specimen.along == "x" else "x")
    return rectangle_trace(turned, path_width_mm)


def strip_traces(specimens, pair_of, layers, path_width_mm, middle_mm):
    """The two sets of paths of the strips, for ``write_thickness_gcode``: ((traces,
    thicknesses, labels) across the strips, printing every layer but the two, (traces,
    thicknesses) along them, printing those two). Every segment of a strip carries the
    strip's whole (layers,) thickness table, so both sets stack each layer on the sum
    of the ones below: ``middle_mm`` everywhere but the pair's layer 2 and N-1."""
    lo, hi = (k - 1 for k in layer_numbers(layers))
    across, along = ([], [], []), ([], [])
    for s in specimens:
        bottom, top = pair_of[s.id]
        per_layer = np.full(layers, float(middle_mm))
        per_layer[lo], per_layer[hi] = bottom, top
        for traces, tr in ((across, transverse_trace(s, path_width_mm)),
                           (along, rectangle_trace(s, path_width_mm))):
            traces[0].append(tr)
            traces[1].append(np.tile(per_layer, (len(tr) - 1, 1)))
        across[2].append("%s bottom_mm=%g top_mm=%g (layers %d and %d)"
                         % (specimen_label(s), bottom, top, lo + 1, hi + 1))
    return across, along


def template(specimens, pair_of, profile_name, layers, middle_mm):
    """The CSV to fill in after the bath, with instructions as ``#`` comments."""
    two, last = layer_numbers(layers)
    return bilayer.strip_template(
        "# hostd calibration of the layers across for profile %s: %d strips %g x %g mm."
        " Layers %d and %d print along the %g mm side, layer %d thinner than layer %d by the"
        " difference in each row (bottom_mm: layer %d, top_mm: layer %d); every other layer"
        " prints across the strip at %g mm."
        % (profile_name, len(specimens), LENGTH_MM, WIDTH_MM, two, last, LENGTH_MM, two, last,
           two, last, middle_mm),
        "across", " The strips also narrow; only their curl along the length is measured.",
        specimens, pair_of, profile_name)


def fit_c(measured, shrink, layers):
    """``c_across`` of ``kappa = c_across * lever(N) * (sigma_2 - sigma_{N-1}) / h``
    through the origin: :func:`pipeline.profiles.bilayer.fit_c` with :func:`lever`."""
    return bilayer.fit_c(measured, shrink, layers, lever=lever(layers))
