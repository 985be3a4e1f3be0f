"""The triangles a stripe phase is drawn on, with what no print direction changes.

A plan draws stripes along three direction fields on one layout (the lower layers',
the upper layers', the layers across); the edges, their cotangent weights, the
vertices' areas, the sparse pattern of the stripe energy and the triangles split in
four for the finer phase (:mod:`pipeline.paths.refine`) are the same for all three, so
they are worked out once per sheet.
"""

from functools import cached_property

import numpy as np
import scipy.sparse as sp

from pipeline.geometry import face_sides, signed_areas_2d


class Sheet:
    """Triangles in the plane: ``xy`` (n, 2) mm, ``faces`` (m, 3) int."""

    def __init__(self, xy, faces):
        self.xy = np.asarray(xy, dtype=float)
        self.faces = np.asarray(faces)

    @cached_property
    def _sides(self):
        return face_sides(self.faces)

    @property
    def edges(self):
        """(e, 2) int: every side once, the smaller vertex first, rows sorted."""
        return self._sides[1]

    @cached_property
    def boundary(self):
        """(k,) int: the outer boundary's vertices in order
        (:func:`pipeline.paths.isoline.boundary_loop`)."""
        from pipeline.paths.isoline import boundary_loop
        return boundary_loop(self.faces)

    @cached_property
    def face_area(self):
        """(m,) mm2."""
        return np.abs(signed_areas_2d(self.xy, self.faces))

    @cached_property
    def vertex_area(self):
        """(n,) mm2: a third of each triangle round the vertex."""
        return np.bincount(self.faces.ravel(), np.repeat(self.face_area / 3, 3), len(self.xy))

    @property
    def face_edges(self):
        """(m, 3) int: the edge (row of :attr:`edges`) of each triangle's side k, from
        corner k to corner k + 1."""
        return self._sides[0]

    @cached_property
    def edge_vectors(self):
        """(e, 2) mm: each edge from its first vertex to its second."""
        i, j = self.edges.T
        return self.xy[j] - self.xy[i]

    @cached_property
    def weight_sums(self):
        """(n,): the cotangent weights of each vertex's edges summed (the stripe
        energy's diagonal)."""
        i, j = self.edges.T
        w = self.weights
        return np.bincount(np.concatenate([i, j]), np.concatenate([w, w]), len(self.xy))

    @cached_property
    def weights(self):
        """(e,) cotangent weights, kept positive (obtuse corners would make the stripe
        problem indefinite)."""
        P = self.xy[self.faces]
        w = np.zeros(len(self.edges))
        for k in range(3):
            u, v = P[:, k] - P[:, (k + 2) % 3], P[:, (k + 1) % 3] - P[:, (k + 2) % 3]
            cross = np.abs(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0])
            cot = np.einsum("mc,mc->m", u, v) / np.maximum(cross, 1e-12)
            np.add.at(w, self.face_edges[:, k], 0.5 * cot)
        return np.maximum(w, 1e-3 * max(float(np.median(np.abs(w))), 1e-12))

    @cached_property
    def pattern(self):
        """The stripe energy's sparse pattern over the vertices' real and imaginary
        parts, laid out as :meth:`matrix` fills it: (indices, indptr) of the (2n, 2n)
        CSR matrix (int32, columns sorted in each row), and for each entry the one of
        ``[diag (n,), block (4, e) flat]`` it holds ((nnz,) int32; entry (2 j + a,
        2 i + b) of edge (i, j) and its transpose hold ``block[2 a + b]``).

        Row 2 v + a holds columns 2 w and 2 w + 1 of each neighbour w in order, with
        the diagonal between the neighbours below v and those above, so every slot is
        counted from the vertex degrees: no COO triplets to sort (on the 175 mm dome's
        finer triangles those were the toolpath stage's peak, 120 MB). The matrix is
        then one gather, where scattering each part to its slots took three times as
        long (26 ms on the dome's finer triangles, for each of a plan's three sets)."""
        n, (i, j) = len(self.xy), self.edges.T
        e = len(i)
        below = np.bincount(j, minlength=n)              # neighbours w < v
        above = np.bincount(i, minlength=n)              # neighbours w > v
        indptr = np.zeros(2 * n + 1, np.int64)
        np.cumsum(np.repeat(2 * (below + above) + 1, 2), out=indptr[1:])
        # Edges come sorted by (i, j): vertex i's neighbours above it are a run in
        # order of j; a stable sort by j orders vertex j's neighbours below it by i.
        k = np.arange(e)
        rank_up = below[i] + k - (np.cumsum(above) - above)[i]
        by_j = np.argsort(j, kind="stable")
        rank_down = np.empty(e, np.int64)
        rank_down[by_j] = k - (np.cumsum(below) - below)[j[by_j]]
        diag_slot = indptr[:-1] + np.repeat(2 * below, 2)
        indices = np.empty(indptr[-1], np.int32)
        source = np.empty(indptr[-1], np.int32)
        indices[diag_slot] = np.arange(2 * n)
        source[diag_slot] = np.repeat(np.arange(n), 2)
        for a in range(2):
            for b in range(2):
                entry = n + (2 * a + b) * e + k
                slot = indptr[2 * j + a] + 2 * rank_down + b
                indices[slot], source[slot] = 2 * i + b, entry
                # Past the diagonal, which sits before the neighbours above.
                slot = indptr[2 * i + b] + 2 * rank_up + a + 1
                indices[slot], source[slot] = 2 * j + a, entry
        return indices, indptr.astype(np.int32), source

    def matrix(self, block, diag):
        """The (2n, 2n) CSR matrix whose entries (2 j + a, 2 i + b) and (2 i + b, 2 j + a)
        are ``block[2 a + b]`` ((4, e), per edge (i, j)) and whose diagonal is ``diag``
        ((n,), the same for a vertex's two parts)."""
        indices, indptr, source = self.pattern
        data = np.concatenate([diag, np.asarray(block, float).ravel()])[source]
        return sp.csr_matrix((data, indices, indptr), shape=(2 * len(self.xy),) * 2)

    @cached_property
    def quartered(self):
        """Every triangle split in four at its sides' midpoints: (the finer
        :class:`Sheet`, (m4,) the triangle each came from, (k, 2) the side each new
        vertex halves, new vertices numbered from n in this order)."""
        xy, faces, parent, sides = split_mesh(self.xy, self.faces, np.ones(len(self.faces), bool),
                                              self._sides)
        return Sheet(xy, faces), parent, sides


def _row_count(b):
    """How many of each row of ``b`` ((m, 3) bool) are set: (m,) int."""
    return b[:, 0].astype(np.int64) + b[:, 1] + b[:, 2]


def split_mesh(xy, faces, red, sides=None):
    """The triangles ``red`` ((m,) bool) split in four at their sides' midpoints, and in
    two those of their neighbours that share one split side (three-way splits would need
    more, so a neighbour with two split sides is split in four too). ``sides``: the
    triangles' sides and edges (:func:`pipeline.geometry.face_sides`) where known.

    Returns (xy (n2, 2), faces (m2, 3), parent: (m2,) the input triangle of each, sides:
    (n2 - n, 2) the two ends of the side each new vertex halves, in the order of
    :func:`pipeline.geometry.unique_edges`)."""
    n = len(xy)
    red = np.asarray(red, bool).copy()
    if not red.any():
        return xy, faces, np.arange(len(faces)), np.zeros((0, 2), np.int64)
    fe, edges = face_sides(faces) if sides is None else sides
    while True:
        marked = np.zeros(len(edges), bool)
        marked[fe[red].ravel()] = True
        # Summed column by column: numpy's sum along a row of three took ten times as long
        # (0.08 s of the 175 mm coast tile's stripes).
        count = _row_count(marked[fe])
        more = ~red & (count >= 2)
        if not more.any():
            break
        red |= more
    me = np.flatnonzero(marked)
    mid = np.full(len(marked), -1)
    mid[me] = n + np.arange(len(me))
    sides = edges[me]
    mid, marked = mid[fe], marked[fe]
    xy2 = np.vstack([xy, 0.5 * (xy[sides[:, 0]] + xy[sides[:, 1]])])
    r = np.flatnonzero(red)
    A, B, C = faces[r].T
    ab, bc, ca = mid[r, 0], mid[r, 1], mid[r, 2]
    out = [np.stack(t, axis=1) for t in ((A, ab, ca), (ab, B, bc), (ca, bc, C), (ab, bc, ca))]
    parent = [r] * 4
    g = np.flatnonzero(~red & (count == 1))
    k = np.argmax(marked[g], axis=1)                   # the split side: corners k, k + 1
    i0, i1, i2 = faces[g, k], faces[g, (k + 1) % 3], faces[g, (k + 2) % 3]
    m = mid[g, k]
    out += [np.stack([i0, m, i2], axis=1), np.stack([m, i1, i2], axis=1)]
    parent += [g, g]
    keep = np.flatnonzero(count == 0)
    out.append(faces[keep])
    parent.append(keep)
    return xy2, np.concatenate(out), np.concatenate(parent), sides
