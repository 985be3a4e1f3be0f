"""The free layout's sheet checked once, coarse to fine.

:func:`pipeline.simulation.programmed.simulate_free` chooses the sheet's program by
trial settles: the bilayer from the bath, then the twist and two stacks with layers
across probed from its rest, and the one kept settled on. On a real 175 mm tile those
are five settles of the full mesh (15 000 vertices), most of a plan's time. The shell
is mesh-converged, so a sheet of 2.5 mm triangles rests where the 1 mm one does (the
Vancouver tile at 175 mm: 1.016 mm from the target against 0.985 mm, the same program
chosen): the trials run there, and only the program chosen is made on the full mesh and
settled once, from the coarse sheet's rest carried onto it (the Vancouver tile: 76
iterations instead of 583).

:func:`reference_settle` settles a program chosen so the way the trials do, on the full
mesh from the bath; the benchmark compares the two.
"""

import dataclasses
import time

import numpy as np

from pipeline.errors import MeshingError
from pipeline.meshing.grid import build_grid_mesh
from pipeline.simulation import programmed
from pipeline.simulation.resample import locate

# Triangle size of the sheet the trials settle on: 2.5 mm rests within 3 % of the 1 mm
# sheet on the Vancouver tile at 175 mm (2 mm: 2 %, 3 mm: 1 %, each choosing the same
# program) at a sixth of its vertices. 3 mm took 0.3-1.7 s off the simulate stage of the
# 175 mm tiles and the rough terrain, but a 40 mm dome's trials then rested 21 % further
# from its target than its plan's mesh did (0.436 against 0.360 mm; 6 % at 2.5 mm).
COARSE_MM = 2.5
# So a large sheet's trials settle on triangles up to COARSE_MAX_MM, as long as the diagonal
# of its bounding box holds COARSE_ACROSS of them (from a 125 mm diagonal on, 3 mm from 150
# mm; a disk's diagonal is 1.41 times its diameter, a square's its diameter): 3 mm rests
# as 2.5 mm does on the 150-175 mm models (each within 8 % of its full settle), and a 60
# mm dome, whose trials at 3 mm rest 8 % off (3 % at 2.5 mm), keeps 2.5 mm.
COARSE_MAX_MM = 3.0
COARSE_ACROSS = 50
# The full mesh starts from the coarse sheet's rest, which has crept along the soft modes
# already: it only relaxes what the coarse triangles could not bend, and is taken to be at
# rest when it moves this much less than a sheet settling from the bath must (times its
# diameter, RMS over ten iterations). The Vancouver tile at 175 mm: 0.990 mm from the
# target after 20 iterations, 0.982 mm at the bath's rest tolerance after 76. Its curvature
# read finer (pipeline.fitting.program_relief), it creeps on for 70 (0.298 mm; 0.287 after
# 10): at 3e-4 a 175 mm tile saves 3 s, but the held 60 mm terrain tile of the hold's test
# then ends 0.321 % of its diameter from its target, past its 0.32 % limit.
FINE_REST_TOL = 1e-4
# The trials run on the plan's own mesh where it is not this much finer than the coarse
# sheet: a sheet barely coarser would save little and carry the answer for nothing.
FINER = 1.8


def simulate_free(hf, mesh, flat, profile, twist=True, across=True, coarse_mm="auto",
                  reference=False, relief=None):
    """As :func:`pipeline.simulation.programmed.simulate_free`, the program chosen on a
    sheet of ``coarse_mm`` triangles (:func:`coarse_sheet`; "auto": :func:`coarse_spacing_mm`)
    and only it made on ``mesh`` and settled there once, from the coarse sheet's rest
    carried onto it. Where ``mesh`` is not :data:`FINER` times finer (or ``coarse_mm`` is
    None) the trials run on it.
    With ``reference`` the program chosen settles on ``mesh`` from the bath instead
    (:func:`reference_settle`), for comparison. ``relief``: as
    :func:`pipeline.simulation.programmed.simulate_free`'s.

    Returns (CurvatureProgram with the coarse sheet's ``twist`` and ``across``
    comparisons, SimResult of ``mesh``: ``coarse_iterations`` those of the coarse sheet's
    settles, ``timing_s`` {coarse, full, total} and the CPU seconds of the first two,
    ``coarse_cpu`` and ``full_cpu``)."""
    t0, c0 = time.perf_counter(), time.process_time()
    coarse = None
    if coarse_mm == "auto":
        coarse_mm = coarse_spacing_mm(mesh)
    if coarse_mm is not None and coarse_mm >= FINER * spacing_mm(mesh):
        try:
            coarse = coarse_sheet(hf, mesh, flat, coarse_mm)
        except MeshingError:
            coarse = None       # a footprint too narrow for the coarse grid
    if coarse is None:
        return programmed.simulate_free(hf, mesh, flat, profile, twist=twist, across=across,
                                        relief=relief)
    cmesh, cflat = coarse
    tally = []
    cprog, csim = programmed.simulate_free(hf, cmesh, cflat, profile, twist=twist,
                                           across=across, tally=tally, relief=relief)
    t1, c1 = time.perf_counter(), time.process_time()
    which = programmed.choice_of(cprog)
    prog, settle = _chosen(hf, mesh, flat, profile, which, twist, relief=relief)
    if reference:
        sim = reference_settle(hf, mesh, flat, profile, which, twist, program=(prog, settle),
                               relief=relief)
    else:
        sim = settle(start=carried(cmesh, csim.vertices, mesh.vertices),
                     rest_tol=FINE_REST_TOL)
    # The comparisons' figures are the coarse sheet's: they say on which sheet.
    prog.twist = None if cprog.twist is None else dict(cprog.twist, coarse_mm=coarse_mm)
    prog.across = _across_report(cprog.across, prog, coarse_mm)
    t2, c2 = time.perf_counter(), time.process_time()
    sim = dataclasses.replace(sim, coarse_iterations=sum(tally), full_iterations=sim.iterations,
                              timing_s={"coarse": t1 - t0, "full": t2 - t1, "total": t2 - t0,
                                        "coarse_cpu": c1 - c0, "full_cpu": c2 - c1})
    return prog, sim


def reference_settle(hf, mesh, flat, profile, which, twist=True, program=None, relief=None):
    """The program ``which`` (:data:`pipeline.simulation.programmed.CHOICES`) settled on
    ``mesh`` the way the trials settle the one they keep: the bilayer from the bath,
    then ``which`` from the bilayer's rest (no probe cap). ``program``: (program,
    ``settle``) of ``which`` already made on ``mesh``. Returns SimResult."""
    make = programmed.Programs(hf, mesh, flat, profile, relief=relief)
    sim = make.settle(make.programmed(0.0))
    if which == "bilayer":
        return sim
    _, settle = program or make.chosen(which, twist)
    return programmed._continued(settle(start=sim.vertices), sim)


def _chosen(hf, mesh, flat, profile, which, twist, relief=None):
    return programmed.Programs(hf, mesh, flat, profile, relief=relief).chosen(which, twist)


def _across_report(coarse_across, prog, coarse_mm):
    """The coarse sheet's ``across`` comparison, with the relaid layout's solve the one
    on the plan's mesh where that layout is the one printed."""
    if coarse_across is None:
        return None
    out = dict(coarse_across, coarse_mm=coarse_mm)
    relaid = (prog.across or {}).get("relaid")
    if relaid is not None:
        out["relaid"] = dict(relaid, chosen=coarse_across["chosen"] == 0)
    return out


def coarse_spacing_mm(mesh):
    """The trials' triangle size for ``mesh`` (mm): :data:`COARSE_MM`, or coarser up to
    :data:`COARSE_MAX_MM` where the diagonal of the target's bounding box (x, y) holds
    :data:`COARSE_ACROSS` triangles of it."""
    V = np.asarray(mesh.vertices, dtype=float)[:, :2]
    diameter = float(np.linalg.norm(V.max(axis=0) - V.min(axis=0)))
    return float(np.clip(diameter / COARSE_ACROSS, COARSE_MM, COARSE_MAX_MM))


def spacing_mm(mesh):
    """Median edge length of ``mesh`` over the target's footprint (x, y): mm."""
    V = np.asarray(mesh.vertices, dtype=float)[:, :2]
    F = np.asarray(mesh.faces)
    return float(np.median(np.linalg.norm(V[F[:, 1]] - V[F[:, 0]], axis=1)))


def coarse_sheet(hf, mesh, flat, coarse_mm=COARSE_MM):
    """The layout ``flat`` of ``mesh`` carried onto a grid of ``hf`` every ``coarse_mm``:
    each coarse vertex where the layout's map puts its point of the target, each coarse
    triangle the print direction and shrink of the fine one under its centre.
    Returns (coarse Mesh, FreeLayout)."""
    cmesh = build_grid_mesh(hf, coarse_mm)
    V = np.asarray(mesh.vertices, dtype=float)[:, :2]
    F = np.asarray(mesh.faces, dtype=np.int64)
    CV = np.asarray(cmesh.vertices, dtype=float)[:, :2]
    CF = np.asarray(cmesh.faces, dtype=np.int64)
    xy = _interpolated(V, F, np.asarray(flat.xy, dtype=float), CV)
    under, _ = locate(V, F, CV[CF].mean(axis=1))
    d = np.asarray(flat.direction, dtype=float)[under]
    d /= np.maximum(np.linalg.norm(d, axis=1), 1e-12)[:, None]
    return cmesh, dataclasses.replace(flat, xy=xy, direction=d,
                                      sigma=np.asarray(flat.sigma)[under])


def carried(cmesh, shape, vertices):
    """The coarse sheet's 3-D ``shape`` ((k, 3) mm, at ``cmesh``'s vertices) carried to
    the points of the target ``vertices`` ((n, 3) mm) by where they lie over the coarse
    target: (n, 3) mm."""
    return _interpolated(np.asarray(cmesh.vertices, dtype=float)[:, :2],
                         np.asarray(cmesh.faces, dtype=np.int64),
                         np.asarray(shape, dtype=float),
                         np.asarray(vertices, dtype=float)[:, :2])


def _interpolated(V2, faces, values, points):
    """``values`` ((n, c), at ``V2``) linearly inside ``faces`` at ``points`` ((k, 2)),
    beyond the mesh's edge by the nearest triangle's plane: (k, c)."""
    which, bary = locate(V2, faces, points)
    return np.einsum("kj,kjc->kc", bary, values[faces[which]])
