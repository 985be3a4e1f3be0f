"""Tool paths along any direction field: stripe patterns (Knoppel, Crane, Pinkall and
Schroder, "Stripe Patterns on Surfaces", 2015).

The free-direction layout gives each triangle a print direction ``d``; such a field
turns, has curl and has singular points, so no single scalar field has level sets along
it. Instead, a complex value per vertex whose phase advances by 2 pi per path width
across ``d``: the smallest eigenvector of a sparse Hermitian problem, with the sign
flips of a line field (``d`` and ``-d`` are the same direction) written as complex
conjugation. The paths are the phase's level sets; where the phase winds around a
triangle (a fork of the stripes) or the line field turns over (a branch point), the
triangle holds no path, and paths end there. The layout's triangles are too coarse for
a direction that turns as fast as on real terrain; the phase is drawn on finer ones
(:mod:`pipeline.paths.refine`) and the path ends that crowd other paths around the
forks are cut back (:mod:`pipeline.paths.ends`).
"""

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from pipeline.geometry import (hat_gradients, polyline_length, polyline_lengths, quarter_turn,
                               signed_areas_2d)
from pipeline.linalg import factor_spd
from pipeline.paths.ends import REACH
from pipeline.paths.phase import BRANCH, FORK, corner_phases, stripe_matrix, vertex_line_field
from pipeline.paths.sheet import Sheet


# Stripe pieces whose ends lie up to this many path widths apart are joined into one
# path where the hop runs over other paths for no more than OVER_FACTOR widths (the
# profile's ``toolpath.hop_reach_widths`` and ``toolpath.hop_over_widths``); over them
# it moves dry (:mod:`pipeline.paths.dry`). Lower layers, traces a layer at reach 9, 25
# and 40: real tiles at 175 mm 33, 1 and 1, 24, 1 and 1; saddle 38, 3 and 1; elongated
# peak 23, 2 and 1 (the ends each end is offered: :data:`pipeline.paths.links.NEAREST`);
# a stripe set of a real tile takes as long either way (1.3 s).
JOIN_FACTOR = 40.0
OVER_FACTOR = 40.0
# An end at the sheet's edge is joined to the path beside it by leaving out that path's
# tail along the edge where the tail is no longer than this many path widths (the
# profile's ``toolpath.rim_tail_widths``; see :mod:`pipeline.paths.rims`).
RIM_TAIL = 20.0

# How far the paths' mean spacing may stray from the path width before the phase is
# solved again at a corrected width (see :func:`stripe_phase_at_width`).
WIDTH_TOL = 0.01
# The inverse iteration's shift below zero, in units of the energy's mean diagonal over
# the mean vertex area: small against the smallest eigenvalue, so that each step divides
# the others by their ratio to it, and still enough that the matrix factors as positive
# definite where that eigenvalue is 0 (parallel paths). At 1e-3 it was 4 times the
# smallest eigenvalue of the 175 mm dome's lower set: 47 steps instead of 11.
SHIFT = 1e-6

class Stripes(NamedTuple):
    """The paths :func:`plan_stripes` draws, before they are cut back and joined."""

    chains: list      # of ((k, 2) points mm, (k - 1,) sigma, closed)
    pathless: object  # (m,) int8: why each triangle holds no path or part of one (as
    #                   :func:`corner_phases`; a branch before a fork)
    bare_mm2: float   # the area of the finer triangles that hold no path
    faces: list       # of (k - 1,) int: the layout's triangle each segment lies in


def stripe_phase(sheet, normal, width_mm, near=None):
    """Phase per vertex of ``sheet`` (:class:`pipeline.paths.sheet.Sheet`; (n,) rad)
    whose gradient is ``2 pi / width`` along the line field ``normal`` (per face, unit;
    the paths run across it), and the vertex field ``X`` ((n, 2)) the phase is measured
    along. ``near``: (n,) rad, a phase the answer is expected close to (one solved at a
    nearby width), where the solve starts."""
    X = vertex_line_field(sheet, normal)
    A, diag = stripe_matrix(sheet, X, width_mm)
    mass = np.repeat(sheet.vertex_area, 2)
    start = None if near is None else np.column_stack([np.cos(near), np.sin(near)]).ravel()
    vec = smallest_eigenvector(A, mass, -SHIFT * float(diag.mean()) / float(mass.mean()),
                               start=start)
    psi = vec[0::2] + 1j * vec[1::2]
    return np.angle(psi), X


def stripe_phase_at_width(sheet, normal, width_mm, tol=WIDTH_TOL):
    """:func:`stripe_phase` whose paths lie ``width_mm`` apart as drawn, not only as asked.

    Where the field spreads and the stripes fork often (a saddle's paths fan out from
    its middle), the pattern that costs least draws its paths closer than asked: on a
    hyperbolic paraboloid 5 % closer, so the G-code laid 5 % more plastic than the sheet
    holds and 3.3 % of the sheet was printed twice. The mean spacing the phase draws is
    measured, and where it is off by more than ``tol`` the phase is solved once more at
    the width that corrects it. Returns (phase, X, the width solved at)."""
    phase, X = stripe_phase(sheet, normal, width_mm)
    u, bare = corner_phases(sheet.xy, sheet.faces, phase, X, width_mm)
    drawn = drawn_spacing(sheet.xy, sheet.faces, u, bare == 0)
    if drawn is None or abs(drawn / width_mm - 1.0) <= tol:
        return phase, X, width_mm
    asked = width_mm * width_mm / drawn
    # The pattern at the corrected width is the first one a few per cent denser: started
    # from it the solve takes 4 iterations instead of 11 on the 175 mm dome.
    phase, X = stripe_phase(sheet, normal, asked, near=phase)
    return phase, X, asked


def drawn_spacing(xy, faces, u, ok):
    """The mean distance (mm) between the paths that the path index ``u`` ((m, 3) per
    corner, :func:`corner_phases`) draws in the triangles ``ok`` ((m,) bool), as the
    material sees it: their area over the length of path in them (path length per area
    is the index's gradient). None where no triangle holds paths."""
    gphi, area = hat_gradients(np.asarray(xy, dtype=float), faces[ok])
    grad = np.hypot(*np.einsum("mi,mid->md", u[ok], gphi).T)
    area = np.abs(area)
    if not (area * grad).sum() > 0:
        return None
    return float(area.sum() / (area * grad).sum())


def smallest_eigenvector(A, mass, shift, tol=1e-2, max_iterations=100, start=None):
    """The eigenvector of ``A x = lambda diag(mass) x`` with the smallest eigenvalue, from
    a fixed start (or ``start``, (2n,)) on one factorisation of ``A - shift M`` (``A``
    symmetric positive semi-definite, ``shift`` < 0): (2n,).

    Where the two smallest eigenvalues nearly coincide (a field with several singular
    points) any vector of their span is an equally good stripe pattern; ARPACK, asked
    for one of the pair, started from a random vector and at times iterated for many
    minutes. Here the answer is the same every run and the iterations are capped.

    Each solve extends a Lanczos basis (M-orthonormal, kept orthogonal in full), and two
    vectors one solve on are tried: from the Ritz vector of the smallest eigenvalue, and
    from the vector inverse iteration would have reached; the first within ``tol`` is
    taken. Where the smallest eigenvalues crowd (the 175 mm dome's rings on a 1.25 mm
    mesh) inverse iteration creeps through them: its three stripe sets took 50, 47 and 27
    solves (and 28 more for a width corrected), the Ritz vector 10 each. Where they do
    not crowd, inverse iteration's vector comes as early and is the one taken, so no
    pattern takes more solves than inverse iteration alone (the coast tile at 175 mm: 7, 8
    and 6 solves, against 11, 17 and 9). Both vectors and their residuals are worked out on
    the basis's coordinates, with no product by ``A``.
    """
    # A - shift M is symmetric positive definite for shift < 0 (A is an energy).
    lu = factor_spd(A - shift * sp.diags(mass))
    x = np.random.default_rng(0).standard_normal(A.shape[0]) if start is None else start
    Q = np.empty((max_iterations + 1, A.shape[0]))
    Q[0] = x / np.sqrt(np.dot(x, mass * x))
    alpha, beta = np.zeros(max_iterations), np.zeros(max_iterations)
    power = np.ones(1)          # inverse iteration's vector, on the basis
    for k in range(max_iterations):
        w = lu.solve(mass * Q[k])
        for _ in range(2):      # twice: once loses orthogonality as the vectors converge
            c = Q[:k + 1] @ (mass * w)
            w -= c @ Q[:k + 1]
            alpha[k] += c[k]
        beta[k] = np.sqrt(np.dot(w, mass * w))
        # K Q = Q T + beta_k q_k+1 e_k^T with K = (A - shift M)^-1 M: K of a vector is T
        # on its coordinates and beta_k times its last one along q_k+1.
        T = np.diag(alpha[:k + 1]) + np.diag(beta[:k], 1) + np.diag(beta[:k], -1)
        # Where the basis spans the space (a sheet of a few vertices) beta_k is round-off
        # and q_k+1 noise, but it enters every vector times beta_k.
        Q[k + 1] = w / beta[k]
        step = lambda v: np.append(T @ v, beta[k] * v[-1])
        ritz = np.linalg.eigh(T)[1][:, -1]
        for before in (ritz, power):
            after = step(before)
            if _relative_residual(before, after, shift) <= tol:
                return after @ Q[:k + 2]
        power = step(power)
        power /= np.linalg.norm(power)
    return power @ Q[:max_iterations + 1]


def _relative_residual(before, after, shift):
    """The eigen-residual over the Rayleigh quotient of the vector whose basis coordinates
    are ``after`` ((k + 2,)), K of the one at ``before`` ((k + 1,)): since
    ``(A - shift M) after = M before``, its product by ``A`` is M of ``shift after +
    before``, on the same (M-orthonormal) basis."""
    Aa = shift * after + np.append(before, 0.0)
    n2 = np.dot(after, after)
    lam = np.dot(after, Aa) / n2
    r = Aa - lam * after
    return np.sqrt(np.dot(r, r) / n2) / max(abs(lam), 1e-12)


# Segments cut at a time: with the per-segment temporaries of all of them at once the
# cut took 63 MB on the 175 mm dome's finer triangles, in chunks 37 (most of it the result).
SEGMENT_CHUNK = 1 << 16


def stripe_segments(xy, faces, u, ok, chunk=SEGMENT_CHUNK):
    """Level sets ``u = k + 1/2`` in every triangle that holds paths.

    Returns (pts (s, 2, 2) mm, keys (s, 2) int64 shared by the segments that meet at a
    point, face (s,) int)."""
    xy = np.asarray(xy, dtype=float)
    f_ok = np.flatnonzero(ok)
    uf = u[f_ok]
    # Column by column: a reduction along rows of three is twenty times slower.
    lo = np.ceil(np.minimum(np.minimum(uf[:, 0], uf[:, 1]), uf[:, 2]) - 0.5)
    hi = np.floor(np.maximum(np.maximum(uf[:, 0], uf[:, 1]), uf[:, 2]) - 0.5)
    count = np.maximum(hi - lo + 1, 0).astype(np.int64)
    f = np.repeat(f_ok, count)
    first = np.repeat(lo, count)
    level = first + (np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)) + 0.5
    pts = np.empty((len(f), 2, 2))
    keys = np.empty((len(f), 2), np.int64)
    for at in range(0, len(f), chunk):
        part = slice(at, at + chunk)
        _cut(xy, faces, u, f[part], level[part], pts[part], keys[part])
    return pts, keys, f


def _cut(xy, faces, u, f, level, pts, keys):
    """Write into ``pts`` ((s, 2, 2) mm) and ``keys`` ((s, 2) int64) the two ends of the
    level set ``u = level`` ((s,)) in each triangle ``f`` ((s,)), as
    :func:`stripe_segments` returns them."""
    uu = u[f] - level[:, None]
    uu = np.where(np.abs(uu) < 1e-9, 1e-9, uu)
    neg = uu < 0
    cross = neg != np.roll(neg, -1, axis=1)                  # side k: corners k, k+1
    tri = faces[f]
    n = len(xy)
    idx = np.arange(len(f))
    for which in (0, 1):
        k = np.argmax(cross, axis=1) if which == 0 else 2 - np.argmax(cross[:, ::-1], axis=1)
        a, b = tri[idx, k], tri[idx, (k + 1) % 3]
        ua, ub = uu[idx, k], uu[idx, (k + 1) % 3]
        t = ua / (ua - ub)
        pts[:, which] = xy[a] + (xy[b] - xy[a]) * t[:, None]
        # The same point seen from the triangle across the side: measured from the
        # smaller vertex id, rounded well below a micrometre.
        tt = np.where(a < b, t, 1 - t)
        keys[:, which] = ((np.minimum(a, b) * n + np.maximum(a, b)) * 2 ** 20
                          + np.rint(tt * (2 ** 20 - 1)).astype(np.int64))


def chain(keys):
    """Join segments that share end points into polylines (either direction).

    Returns a list of (the ends each segment is entered at, in order (end ``e`` is end
    ``e % 2`` of segment ``e // 2``), closed): open polylines first, each walked from
    its lower free end, in the order of that end; then the closed ones, each entered
    at end 0 of its lowest segment, in the order of that segment."""
    s = len(keys)
    if s == 0:
        return []
    flat = keys.ravel()
    order = np.argsort(flat, kind="stable")
    sk = flat[order]
    same = np.flatnonzero(sk[1:] == sk[:-1])
    partner = np.full(2 * s, -1, dtype=np.int64)
    partner[order[same]] = order[same + 1]
    partner[order[same + 1]] = order[same]
    ends = np.arange(2 * s)
    # Entered at end e, the walk leaves by e ^ 1 and enters the next segment at succ[e].
    succ = partner[ends ^ 1]
    free = np.flatnonzero(partner < 0)
    walks = _depth_first_walks(succ, np.r_[free, ends])
    # Open polylines: walked from both free ends, kept from the lower one (the walk
    # leaves by the free end ``last ^ 1``); every node of theirs is then taken, and
    # the walks from the nodes left go round rings, each both ways: entered first at
    # its least end (end 0 of its lowest segment), then at the one after it.
    first = np.array([w[0] for w in walks], np.int64)
    last = np.array([w[-1] for w in walks], np.int64)
    open_ = partner[first] < 0
    keep = np.where(open_, first <= (last ^ 1), first % 2 == 0)
    return ([(w, False) for w, k, o in zip(walks, keep, open_) if k and o]
            + [(w, True) for w, k, o in zip(walks, keep, open_) if k and not o])


def _depth_first_walks(succ, starts):
    """The walks along ``succ`` ((q,) next node, -1 at an end) from each of ``starts``
    in turn that is not yet on an earlier walk, each up to its end or to a node
    already walked: list of (k,) int64.

    Each node has one successor, so the walks are the runs of a depth-first order
    from a chain of virtual nodes, one before each start: one pass over the nodes
    in compiled code, where doubling pointers took twenty (0.35 s of the 175 mm
    dome's 233 thousand segments)."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import depth_first_order
    q, v = len(succ), len(starts)
    has = succ >= 0
    # Node rows: their successor; virtual row i: start i, then virtual node i + 1.
    count = np.r_[has.astype(np.int64), np.full(v - 1, 2), 1]
    indptr = np.r_[0, np.cumsum(count)].astype(np.int32)
    indices = np.empty(indptr[-1], np.int32)
    indices[indptr[:q][has]] = succ[has]
    row = indptr[q:-1]
    indices[row] = starts
    indices[row[:-1] + 1] = q + 1 + np.arange(v - 1)
    # Already of the types the traversal takes: no copies of the graph.
    graph = csr_matrix((np.ones(len(indices)), indices, indptr), shape=(q + v,) * 2)
    order = depth_first_order(graph, q, directed=True, return_predecessors=False)
    edge = np.diff(np.r_[0, (order < q).astype(np.int8), 0])
    order = order.astype(np.int64)
    return [order[a:b] for a, b in zip(np.flatnonzero(edge > 0).tolist(),
                                        np.flatnonzero(edge < 0).tolist())]


def plan_stripes(xy, faces, direction, sigma, width_mm, refine=True, sheet=None):
    """Paths along ``direction`` ((m, 2) unit per face), a path width apart; with
    ``refine`` the phase is carried to finer triangles (:mod:`pipeline.paths.refine`),
    which leaves smaller bare patches where the stripes fork. ``sheet``: the
    :class:`pipeline.paths.sheet.Sheet` of ``xy`` and ``faces`` where the caller keeps
    one for several directions.

    Returns a :class:`Stripes`."""
    d = np.asarray(direction, dtype=float)
    sheet = Sheet(xy, faces) if sheet is None else sheet
    xy = sheet.xy
    normal = quarter_turn(d)
    phase, X, width_mm = stripe_phase_at_width(sheet, normal, width_mm, WIDTH_TOL)
    if refine:
        from pipeline.paths.refine import refine_phase
        xy, sub, phase, X, parent, u, bare = refine_phase(sheet, normal, phase, X, width_mm)
    else:
        sub, parent = faces, np.arange(len(faces))
        u, bare = corner_phases(xy, faces, phase, X, width_mm)
    pathless = np.zeros(len(faces), np.int8)
    np.maximum.at(pathless, parent, bare)
    bare_mm2 = float(np.abs(signed_areas_2d(xy, sub[bare > 0])).sum())
    pts, keys, face = stripe_segments(xy, sub, u, bare == 0)
    walks = chain(keys)
    if not walks:
        return Stripes([], pathless, bare_mm2, [])
    e = np.concatenate([steps for steps, _ in walks])
    size = np.array([len(steps) for steps, _ in walks])
    seg, entry = e // 2, e % 2
    # Each segment's entry point, then where the last one is left: all walks' points
    # gathered at once, then cut apart (a gather per walk took 0.05 s a set).
    last = np.cumsum(size) - 1
    p = pts[np.insert(seg, last + 1, seg[last]), np.insert(entry, last + 1, 1 - entry[last])]
    p = np.split(p, np.cumsum(size + 1)[:-1])
    cut = np.cumsum(size)[:-1]
    seg_sigma = np.split(np.asarray(sigma, dtype=float)[parent[face[seg]]], cut)
    chains = [(q[:-1] if closed else q, sg, closed)
              for q, sg, (_, closed) in zip(p, seg_sigma, walks)]
    return Stripes(chains, pathless, bare_mm2, np.split(parent[face[seg]], cut))



def direction_angles(steps, face, *directions):
    """Angle (degrees) between each path segment (``steps`` (s, 2) mm, from its start to
    its end) and each of ``directions`` ((m, 2), unit, or 0 where a triangle has none)
    in the triangle ``face`` ((s,)) it lies in, and the segment lengths, 0 where there
    is no direction to compare with: one pair of (s,) arrays per direction field."""
    length = np.hypot(steps[:, 0], steps[:, 1])
    out = []
    for direction in directions:
        d = direction[face]
        cos = np.abs(np.einsum("sc,sc->s", steps, d)) / np.maximum(length, 1e-12)
        known = np.hypot(d[:, 0], d[:, 1]) > 0.5
        out.append((np.degrees(np.arccos(np.clip(cos, 0, 1))), length * known))
    return out


def stripe_toolpaths(xy, faces, direction, sigma, width_mm, merge_angle_deg=2.0,
                     merge_sigma=0.005, join_factor=JOIN_FACTOR,
                     over_factor=OVER_FACTOR, refine=True, retract=REACH, level=None,
                     sheet=None, rim_tail_factor=RIM_TAIL):
    """:class:`pipeline.paths.isoline.Toolpaths` along ``direction``: stripe pieces whose
    ends lie up to ``join_factor`` path widths apart joined first where the hop runs over
    other paths for at most ``over_factor`` widths (:mod:`pipeline.paths.links`), closed
    ones bridged to a neighbour (:mod:`pipeline.paths.bridges`), then put in order as
    traces, each printed from its start to its end; each segment
    carries the shrink of the triangle it crosses; the report adds
    ``direction_angle_deg``. With ``refine`` the phase is carried to finer triangles
    (:func:`plan_stripes`); path ends that come within ``retract`` path widths of
    another path are cut back (:func:`pipeline.paths.ends.retract_ends`; 0: not cut).
    With ``level`` ((n,) the height of each vertex) the report also says how far the
    paths turn away from the isolines (``isoline_angle_deg``, as the isoline method's
    report does). ``sheet``: as :func:`plan_stripes`'."""
    import shapely
    from pipeline.paths.isoline import _order_traces, _outline_polygon, finished
    from pipeline.paths.bridges import bridge_rings
    from pipeline.paths.ends import retract_ends
    from pipeline.paths.rims import join_at_rim, leave_slivers, printed_samples
    from pipeline.paths.links import join_ends, merge_joined, path_samples
    from pipeline.paths.stats import _weighted_percentiles
    xy = np.asarray(xy, dtype=float)
    sheet = Sheet(xy, faces) if sheet is None else sheet
    drawn = plan_stripes(xy, faces, direction, sigma, width_mm, refine, sheet)
    # Each segment's triangle rides along with its shrink, through the ends cut back
    # (stacked for all pieces at once, then split: a stack per piece took 0.03 s a set).
    both = np.column_stack([np.concatenate([sg for _, sg, _ in drawn.chains]),
                            np.concatenate(drawn.faces)])
    cut = np.cumsum([len(f) for f in drawn.faces])[:-1]
    chains = [(p, t, closed) for (p, _, closed), t in zip(drawn.chains, np.split(both, cut))]
    if retract > 0:
        chains = retract_ends(chains, width_mm, retract)
    # A piece shorter than a path width is a blob, not a path: where stripes graze the
    # outline's triangles (the 175 mm dome's rim left 14 of 0.03-0.3 mm beside its one
    # trace) each would print a travel and a retraction for less than a bead's width.
    length = polyline_lengths([p for p, _, _ in chains])
    chains = [c for c, mm in zip(chains, length) if c[2] or mm >= width_mm] or chains
    face = np.concatenate([t[:, 1] for _, t, _ in chains]).astype(np.int64)
    chains = [(p, t[:, 0], closed) for p, t, closed in chains]
    raw = [(np.vstack([p, p[:1]]) if closed else p, closed) for p, _, closed in chains]
    outline = _outline_polygon(xy, sheet.boundary)
    footprint = outline.buffer(0.25 * width_mm)
    shapely.prepare(footprint)
    samples, label, tree = path_samples([p for p, _ in raw], width_mm)
    joins = join_ends(chains, width_mm, join_factor * width_mm, footprint, samples, label, tree,
                      over_mm=over_factor * width_mm)
    joined, _ = merge_joined(chains, joins)
    joined, rungs = bridge_rings(joined, width_mm)
    joined, _, tails = join_at_rim(joined, width_mm, outline.boundary, rim_tail_factor,
                                   printed=(samples, tree))
    joined, slivers = leave_slivers(joined, width_mm, outline.boundary, rim_tail_factor)
    # The tails left out print nothing: the figures are those of the paths printed.
    samples, label, tree = printed_samples(samples, label, tree, tails + slivers, width_mm)
    # Every hop a stripe plan prints is one the matching took, within the budget: the
    # isoline method's walk, which also runs on from a trace's end to the nearest by any
    # hop shorter than a few widths, here only puts the traces in order. Its hops ran
    # over paths whatever the budget (a two-field disk with none allowed: 59 mm of hops
    # over paths), and the ends it took were ends the matching had weighed; with the
    # default budget the matching joins every set into one or two traces, and it linked
    # none on any model of the benchmark.
    traces, tsig = _order_traces(joined, [[] for _ in joined], 0.0,
                                 merge_angle_deg, merge_sigma, footprint)
    paths = finished(traces, tsig, raw, xy, faces, None, None, outline, width_mm, len(chains),
                     samples=(samples, label, tree))
    info = paths.info
    fields = {"direction_angle_deg": direction}
    if level is not None:
        from pipeline.layout.curvature import isoline_directions
        fields["isoline_angle_deg"] = isoline_directions(xy, faces, level, level=(0.0, 0.0))
    # Every piece's steps at once: the differences across from one piece to the next
    # are dropped.
    points = np.concatenate([p for p, _ in raw])
    steps = np.delete(np.diff(points, axis=0), np.cumsum([len(p) for p, _ in raw])[:-1] - 1,
                      axis=0)
    for key, (ang, length) in zip(fields, direction_angles(steps, face, *fields.values())):
        info[key] = dict(zip(("p50", "p95"), _weighted_percentiles(ang, length, [50, 95])))
    # Which cure a bare patch needs: forks come from a phase the triangles cannot
    # resolve (or a field with curl), branches from the field's own singular points.
    info["pathless_triangles"] = int((drawn.pathless > 0).sum())
    info["fork_triangles"] = int((drawn.pathless == FORK).sum())
    info["branch_triangles"] = int((drawn.pathless == BRANCH).sum())
    info["pathless_mm2"] = drawn.bare_mm2
    info["ring_bridges"] = len(rungs) // 2
    info["rim_tails"] = len(tails)
    info["rim_tail_mm"] = float(sum(polyline_length(t) for t in tails))
    info["rim_slivers"] = len(slivers)
    info["rim_sliver_mm"] = float(sum(polyline_length(t) for t in slivers))
    return paths
