"""Anderson acceleration of a fixed-point iteration ``x -> g(x)`` (Walker & Ni 2011;
for geometry solvers Peng et al. 2018, "Anderson acceleration for geometry optimization
and physics simulation"). Local/global and projective-dynamics steps creep along a
model's soft modes; the next point taken as the combination of the last few steps whose
residual ``g(x) - x`` is least moves along them. The caller keeps the energy safeguard:
where a mixed point is worse than the plain step, it takes the plain step and
:meth:`Anderson.restart`."""

import numpy as np


class Anderson:
    """The mixing over the last ``window`` steps of one iteration."""

    def __init__(self, window):
        self.window = window
        self.dg, self.df, self.last = [], [], None

    def mixed(self, x, g):
        """The next point after ``x``, whose plain step is ``g`` (arrays of one shape):
        ``g`` itself (the same object) until a step before it is known."""
        f = (g - x).ravel()
        if self.last is not None:
            self.dg.append(g.ravel() - self.last[0])
            self.df.append(f - self.last[1])
            del self.dg[:-self.window], self.df[:-self.window]
        self.last = (g.ravel(), f)
        if not self.df:
            return g
        theta = np.linalg.lstsq(np.stack(self.df, axis=1), f, rcond=None)[0]
        return (self.last[0] - np.stack(self.dg, axis=1) @ theta).reshape(g.shape)

    def restart(self):
        """Forget the steps before the last (after a mixed point was dropped)."""
        self.dg.clear()
        self.df.clear()
