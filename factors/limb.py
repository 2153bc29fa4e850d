"""The pairing of one frame's shaft observations with the two projected limbs.

The limb lines of E and their derivatives are
:func:`graphtrack.geometry.cylinder.limb_line_coefficients`; the factors of
:mod:`factors.shaft_pixels` and :mod:`factors.line_parameter` of one frame share
them, and the choice of limb per observation, through a :class:`LimbPairing`.
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from graphtrack.geometry.cylinder import ShaftAxis, limb_line_coefficients


class LimbPairing:
    """What one frame's shaft factors (one E, one shaft axis) decide together:
    the limb lines of E, computed once for all of them, and the limb of each
    member: the pixel sets of :mod:`factors.shaft_pixels` or the detected
    lines of :mod:`factors.line_parameter`, each with ``costs(L)`` -> (2,),
    its cost against either limb of L (2, 3).

    ``limbs(E, L)`` gives the limb (0 / 1) of every member: the injective
    assignment of members to the two limbs with the least total cost (with
    more than two members, the two best-placed take the limbs injectively and
    the others their nearer limb; a lone member, in a pairing of its own, its
    nearer limb). Two detected shaft edges are two different
    limbs; left to choose alone, both take the nearer one whenever E is off
    by more than half the shaft's image width. Both are cached for the last E,
    so the frame's factors, evaluated at the same E, decide together once."""

    def __init__(self):
        self.members: list = []
        self._key = None
        self._limbs: list[int] = []
        self._lines_key = None
        self._lines = None

    def add(self, member) -> int:
        self.members.append(member)
        return len(self.members) - 1

    def lines(self, E: np.ndarray, axis: ShaftAxis, M: np.ndarray, jacobian: bool = True):
        """:func:`graphtrack.geometry.cylinder.limb_line_coefficients` of E, shared by the
        members (which all carry the frame's axis and M)."""
        key = E.tobytes()
        if key != self._lines_key or (jacobian and self._lines[1] is None and self._lines[2]):
            self._lines_key, self._lines = key, limb_line_coefficients(E, axis, M, jacobian)
        return self._lines

    def limbs(self, E: np.ndarray, L: np.ndarray) -> list[int]:
        key = E.tobytes()
        if key != self._key:
            C = [m.costs(L) for m in self.members]                   # k x (2,)
            if len(C) == 2:  # the usual two edges: the cheaper of the two pairings
                limbs = [0, 1] if C[0][0] + C[1][1] <= C[0][1] + C[1][0] else [1, 0]
            else:
                limbs = [int(np.argmin(c)) for c in C]
                if len(C) > 2:
                    rows, cols = linear_sum_assignment(np.array(C))
                    for r, c in zip(rows, cols):
                        limbs[r] = int(c)
            self._key, self._limbs = key, limbs
        return self._limbs
