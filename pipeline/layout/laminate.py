"""Curvature across the paths: the outer layers printed across them.

A bilayer of paths along ``d`` programs the target's curvature along ``d`` only; what
the target bends across ``d`` (``e^T K e``, a quarter to a half of a real terrain's
curvature) the sheet then settles toward flat, and a terrain's ridges and valleys lose
their cross-section. Here the first and the last layer print across ``d`` (along ``e``,
``d`` turned a quarter left): the lower one shrinks where the target curves up across
``d``, the upper one where it curves down, each as a bimetal's outer ply. The inner
layers carry the metric along ``d`` and the bilayer along it, as the two layer groups do.

The sheet is modelled as a stack of equal-weight layers (the bilayer's convention: the
program's constant ``c`` is calibrated on such a stack), each shrinking by ``s_i``
along its own direction ``n_i``: the mean shrink is ``sum_i s_i n_i n_i^T / N`` and the
natural curvature ``(c / 1.5) * 6 / (N^2 h) * sum_i (N + 1 - 2 i) s_i n_i n_i^T`` (a
layer below the middle that shrinks curls the sheet away from the bed). For two equal
groups along ``d`` this is the bilayer's ``c * (s_bottom - s_top) / h``.

The cost: the outer layers shrink little along ``d`` (none where they print at the
thickest), so the metric along ``d`` has ``(N - 2) / N`` of the shrink range, and the
outer layers shrink the sheet a little across ``d`` (``s_across / N``), which the layout
does not know of.
"""

from dataclasses import dataclass

import numpy as np


def levers(layers):
    """Each layer's distance below the middle in half layers: (N,) ``N + 1 - 2 i``."""
    return (layers + 1 - 2 * np.arange(1, layers + 1)).astype(float)


def curvature_per_lever(thickness_mm, layers, c):
    """Natural curvature (1/mm) of one unit of ``lever * shrink``: (m,)."""
    return (c / 1.5) * 6.0 / (layers * layers * np.asarray(thickness_mm, dtype=float))


@dataclass
class Laminate:
    """Per-triangle shrink of every layer and which layers print across ``d``.

    layer_sigma : (m, N) shrink of each layer (layer 1 on the bed)
    across : (N,) bool, the layer prints across ``d`` (else along it)
    thickness_mm : (m,) the stack's printed thickness
    """

    layer_sigma: np.ndarray
    across: np.ndarray
    thickness_mm: np.ndarray

    def directions(self, direction):
        """Print direction of every layer of every triangle: (m, N, 2) unit."""
        d = np.asarray(direction, dtype=float)
        e = np.stack([-d[:, 1], d[:, 0]], axis=1)
        return np.where(self.across[None, :, None], e[:, None, :], d[:, None, :])

    def _tensors(self, direction):
        n = self.directions(direction)
        return np.einsum("ml,mli,mlj->mlij", self.layer_sigma, n, n)

    def metric(self, direction):
        """Mean shrink tensor (m, 2, 2) in the layout: the sheet's metric after the bath."""
        return self._tensors(direction).mean(axis=1)

    def curvature(self, direction, c):
        """Natural curvature tensor (m, 2, 2) 1/mm in the layout (positive: a dome)."""
        N = self.layer_sigma.shape[1]
        unit = curvature_per_lever(self.thickness_mm, N, c)
        return unit[:, None, None] * np.einsum("l,mlij->mij", levers(N), self._tensors(direction))

    def report(self):
        """The report's ``curvature.across``: which layers, how much they shrink, where."""
        outer = self.layer_sigma[:, self.across]
        return {"layers": [int(i) + 1 for i in np.flatnonzero(self.across)],
                "sigma": {"p95": float(np.percentile(outer, 95)), "max": float(outer.max())},
                "area_fraction": float(np.mean(outer.max(axis=1) > 1e-3))}


def across_laminate(K_target, direction, sigma, thickness_of, layers, s_min, s_max, c):
    """The stack whose outer layers program the target's curvature across ``d``.

    K_target : (m, 2, 2) 1/mm, the target's curvature in the layout frame
    (:func:`pipeline.layout.curvature.target_tensor`); direction : (m, 2) unit ``d``;
    sigma : (m,) the layout's shrink along ``d``; thickness_of : callable, (k,) shrink
    -> (k,) one layer's printed thickness mm; layers : N >= 4. Returns :class:`Laminate`.
    """
    K = np.asarray(K_target, dtype=float)
    d = np.asarray(direction, dtype=float)
    e = np.stack([-d[:, 1], d[:, 0]], axis=1)
    k_along = np.einsum("mi,mij,mj->m", d, K, d)
    k_across = np.einsum("mi,mij,mj->m", e, K, e)
    lever = levers(layers)
    across = np.zeros(layers, dtype=bool)
    across[[0, -1]] = True
    # The inner layers alone carry the metric along d.
    mean = np.clip(np.asarray(sigma, dtype=float) * layers / (layers - 2), s_min, s_max)
    half = np.where(lever[~across] > 0, 0.5, -0.5)
    room = 2.0 * np.clip(np.minimum(mean - s_min, s_max - mean), 0.0, None)
    s = np.empty((len(mean), layers))
    h = layers * thickness_of(mean)
    # The thickness follows the shrink it prints: two rounds settle it to well under a
    # per cent of the curvature.
    for _ in range(3):
        unit = curvature_per_lever(h, layers, c)
        delta = np.clip(k_along / (unit * np.sum(lever[~across] * half)), -room, room)
        outer = np.clip(np.abs(k_across) / (unit * lever[0]) + s_min, s_min, s_max)
        s[:, ~across] = mean[:, None] + delta[:, None] * half[None, :]
        s[:, 0] = np.where(k_across > 0, outer, s_min)
        s[:, -1] = np.where(k_across < 0, outer, s_min)
        h = thickness_of(s.ravel()).reshape(s.shape).sum(axis=1)
    return Laminate(layer_sigma=s, across=across, thickness_mm=h)
