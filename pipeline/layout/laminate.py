"""Curvature across the paths: two layers printed across them.

A bilayer of paths along ``d`` programs the target's curvature along ``d`` (and, with
its halves turned apart, the twist) only; what the target bends across ``d``
(``e^T K e``, a quarter to a half of a real terrain's curvature) the sheet then settles
toward flat, and a terrain's ridges and valleys lose their cross-section. Here two
layers, one in each half of the stack, print across ``d`` (along ``e``, ``d`` turned a
quarter left): the lower one shrinks where the target curves up across ``d``, the upper
one where it curves down, as a bimetal's plies. The layers along ``d`` carry the metric
along ``d``, the bilayer along it and the twist, as the two layer groups do.

The sheet is modelled as a stack of equal-weight layers (the bilayer's convention: the
program's constant ``c`` is calibrated on such a stack), each shrinking by ``s_i``
along its own direction ``n_i``: the mean shrink is ``sum_i s_i n_i n_i^T / N`` and the
natural curvature ``(c_i / 1.5) * 6 / (N^2 h) * sum_i (N + 1 - 2 i) s_i n_i n_i^T`` (a
layer below the middle that shrinks curls the sheet away from the bed). For two equal
groups along ``d`` this is the bilayer's ``c * (s_bottom - s_top) / h``. The constant
``c_i`` is the bilayer's ``c`` for the layers along ``d`` and ``c_across`` for those
across, each calibrated on strips of its own layers (:mod:`pipeline.profiles.bilayer`,
:mod:`pipeline.profiles.across`).

The cost: the layers across shrink nothing along ``d``, so the metric along ``d`` has
``(N - 2) / N`` of the shrink range; the one that shrinks shrinks the sheet a little
across ``d`` too (``s_across / N``), which the layout does not know of; and the layers
across print stripes of their own.
"""

from dataclasses import dataclass

import numpy as np

from pipeline.geometry import quarter_turn


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
    turn_bottom, turn_top : (m,) rad, how far the lower and the upper half of the layers
    along ``d`` turn off it (the twist, as :func:`pipeline.layout.curvature.crossing`),
    or None
    """

    layer_sigma: np.ndarray
    across: np.ndarray
    thickness_mm: np.ndarray
    turn_bottom: np.ndarray = None
    turn_top: np.ndarray = None

    def groups(self):
        """Layer numbers (from 1) of each set of paths: {"lower", "upper" (only where the
        halves turn apart), "across"}: lists."""
        along = np.flatnonzero(~self.across) + 1
        lower = along[:len(along) // 2] if self.turned else along
        out = {"lower": [int(k) for k in lower],
               "across": [int(k) for k in np.flatnonzero(self.across) + 1]}
        if self.turned:
            out["upper"] = [int(k) for k in along[len(along) // 2:]]
        return out

    @property
    def turned(self):
        # Round-off of a twist-free target turns them by 1e-17 rad: no set of paths.
        return self.turn_bottom is not None and bool(
            np.any(np.abs(self.turn_bottom) > 1e-9) or np.any(np.abs(self.turn_top) > 1e-9))

    def directions(self, direction):
        """Print direction of every layer of every triangle: (m, N, 2) unit."""
        from pipeline.layout.curvature import turned
        d = np.asarray(direction, dtype=float)
        e = quarter_turn(d)
        n = np.where(self.across[None, :, None], e[:, None, :], d[:, None, :])
        if self.turned:
            g = self.groups()
            n[:, np.array(g["lower"]) - 1] = turned(d, self.turn_bottom)[:, None, :]
            n[:, np.array(g["upper"]) - 1] = turned(d, self.turn_top)[:, None, :]
        return n

    def _tensors(self, direction):
        n = self.directions(direction)
        return np.einsum("ml,mli,mlj->mlij", self.layer_sigma, n, n)

    def metric(self, direction):
        """Mean shrink tensor (m, 2, 2) in the layout: the sheet's metric after the bath."""
        return self._tensors(direction).mean(axis=1)

    def curvature(self, direction, c, c_across=None):
        """Natural curvature tensor (m, 2, 2) 1/mm in the layout (positive: a dome): the
        layers along ``d`` with the constant ``c``, those across with ``c_across``
        (default ``c``)."""
        N = self.layer_sigma.shape[1]
        # Each layer's own constant: the layers across are calibrated on strips of
        # their own (`hostd calibrate across`), and need not curl as a bilayer does.
        per_layer = np.where(self.across, c if c_across is None else c_across, c)
        unit = curvature_per_lever(self.thickness_mm, N, 1.0)
        return unit[:, None, None] * np.einsum("l,mlij->mij", levers(N) * per_layer,
                                               self._tensors(direction))

    def report(self):
        """The report's ``curvature.across``: which layers, how much they shrink, where."""
        cross = self.layer_sigma[:, self.across]
        return {"layers": [int(i) + 1 for i in np.flatnonzero(self.across)],
                "sigma": {"p95": float(np.percentile(cross, 95)), "max": float(cross.max())},
                "area_fraction": float(np.mean(cross.max(axis=1) > 1e-3))}


def across_laminate(K_target, direction, sigma, thickness_of, layers, s_min, s_max, c,
                    across=None, turn_max_deg=0.0, c_across=None):
    """The stack whose layers across ``d`` program the target's curvature across it.

    K_target : (m, 2, 2) 1/mm, the target's curvature in the layout frame
    (:func:`pipeline.layout.curvature.target_tensor`); direction : (m, 2) unit ``d``;
    sigma : (m,) the layout's shrink along ``d``; thickness_of : callable, (k,) shrink
    -> (k,) one layer's printed thickness mm; layers : N >= 4; across : (N,) bool, the
    layers across ``d`` (default :func:`across_layers`); with ``turn_max_deg`` > 0 the two halves
    of the layers along ``d`` also turn apart for the target's twist; ``c`` the constant
    of the layers along ``d``, ``c_across`` that of the layers across (default ``c``).
    Returns :class:`Laminate`.
    """
    from pipeline.layout.curvature import crossing
    K = np.asarray(K_target, dtype=float)
    d = np.asarray(direction, dtype=float)
    e = quarter_turn(d)
    k_along = np.einsum("mi,mij,mj->m", d, K, d)
    k_across = np.einsum("mi,mij,mj->m", e, K, e)
    lever = levers(layers)
    if across is None:
        across = across_layers(layers)
    lo, hi = np.flatnonzero(across)[[0, -1]]
    # The inner layers alone carry the metric along d.
    mean = np.clip(np.asarray(sigma, dtype=float) * layers / (layers - 2), s_min, s_max)
    # The lower layers along d at mean + delta / 2, the upper at mean - delta / 2, a middle
    # one (odd counts) at the mean: their mean stays the metric's.
    half = 0.5 * np.sign(lever[~across])
    room = 2.0 * np.clip(np.minimum(mean - s_min, s_max - mean), 0.0, None)
    s = np.empty((len(mean), layers))
    h = layers * thickness_of(mean)
    # The thickness follows the shrink it prints: two rounds settle it to well under a
    # per cent of the curvature.
    for _ in range(3):
        unit = curvature_per_lever(h, layers, c)
        unit_across = curvature_per_lever(h, layers, c if c_across is None else c_across)
        delta = np.clip(k_along / (unit * np.sum(lever[~across] * half)), -room, room)
        shrink = np.clip(np.abs(k_across) / (unit_across * lever[lo]) + s_min, s_min, s_max)
        s[:, ~across] = mean[:, None] + delta[:, None] * half[None, :]
        s[:, lo] = np.where(k_across > 0, shrink, s_min)
        s[:, hi] = np.where(k_across < 0, shrink, s_min)
        h = thickness_of(s.ravel()).reshape(s.shape).sum(axis=1)
    lam = Laminate(layer_sigma=s, across=across, thickness_mm=h)
    if turn_max_deg > 0:
        # The halves' twist per unit of s_b sin 2a = -s_t sin 2b is unit * their lever.
        k_twist = np.einsum("mi,mij,mj->m", d, K, e)
        unit = curvature_per_lever(h, layers, c)
        lever_half = np.sum(lever[~across] * (half > 0))
        lam.turn_bottom, lam.turn_top = crossing(
            k_twist / (unit * lever_half), mean + delta / 2, mean - delta / 2, turn_max_deg)
    return lam


def across_layers(layers):
    """The layers printed across ``d``: the second and the second last, (N,) bool. Inside
    the outer layers along ``d`` they leave the bilayer along ``d`` two thirds of its
    lever (six layers) where the outermost would leave it four ninths. Measured (mean
    displacement over the diameter, with the twist) against the first and last layer
    across: starfish 0.54 % against no gain (0.94 %), elongated peak 0.39 against 0.52 %,
    Vancouver 0.52 against 0.63 %; the terrain tile 0.13 against 0.09 %, three islands
    0.29 against 0.26 %, the dome 0.21 against 0.14 %."""
    across = np.zeros(layers, dtype=bool)
    across[[1, -2]] = True
    return across
