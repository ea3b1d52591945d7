"""HTM kinematic error model: commanded position -> actual nozzle position, and its inverse.

All positions are in mm in the machine frame (the homed frame of the firmware, G92 offsets
removed). The model follows the machine-tool HTM method used by Keaveney et al. (2018):

* Every axis ``i`` has a nominal motion ``N_i(q) = Trans(q * e_i)`` and a small-angle error
  HTM ``E_i(q)`` built from its three translation errors (tx, ty, tz; mm) and three rotation
  errors (rx, ry, rz; rad, right-handed about +X/+Y/+Z)::

        E = [[ 1,  -rz,  ry, tx],
             [ rz,  1,  -rx, ty],
             [-ry,  rx,   1, tz],
             [ 0,   0,    0,  1]]

  Scale enters as the linear positioning error ``tx(x) += s_x * x`` (and likewise for Y, Z).
* ``parallel`` kinematics (the paper's Ultimaker; axes independent): the positional error
  contributions of the axes are summed, ``p + sum_i (E_i(q_i) n - n)`` with ``n`` the nozzle
  offset, and the alignment (squareness) HTM ``S`` is applied last.
* serial chains (``bedslinger``: Y, Z, X; ``corexy``: Z, Y, X; first entry nearest the
  workpiece, last carries the nozzle): ``P = N_1 E_1 N_2 E_2 ... N_k E_k n``, rotation errors
  of an axis act on everything it carries (Abbe effects); ``S`` is applied last.
* Alignment HTM (the squareness contract of :mod:`params`)::

        S = [[1, xy, xz, 0],
             [0,  1, yz, 0],
             [0,  0,  1, 0],
             [0,  0,  0, 1]]      (xy, xz, yz in 1e-6 units: um/m)

The forward map is ``actual = S (P - n)`` so that zero errors give ``actual == commanded``.
:meth:`KinematicModel.inverse` returns the command that lands on a desired point to 1e-9 mm.
"""

from __future__ import annotations

from typing import Sequence, Tuple

import numpy as np

from .params import AXES, Params

Vec = Tuple[float, float, float]

CHAINS = {
    "bedslinger": ("y", "z", "x"),
    "corexy": ("z", "y", "x"),
}

INVERSE_TOL_MM = 1e-11
INVERSE_MAX_ITER = 60


class InverseError(ArithmeticError):
    """The inverse iteration did not converge (the model is not invertible there)."""


def _poly_eval(coeffs, q):
    """Evaluate c0 + c1*q + ... (Horner) for scalar or array q."""
    acc = 0.0 * q
    for c in reversed(coeffs):
        acc = acc * q + c
    return acc


class KinematicModel:
    """Forward/inverse kinematic error model built from :class:`~.params.Params`.

    ``forward(p)`` maps a commanded machine position (mm) to where the nozzle actually goes;
    ``inverse(d)`` gives the command for a desired position. When the model is affine (the
    usual case: squareness, scale, constant or linear terms) both are one 3x3 matrix-vector
    product; otherwise the inverse iterates to ``INVERSE_TOL_MM``.
    """

    def __init__(self, params: Params):
        self.params = params
        self.kinematics = params.kinematics
        sq = params.squareness_um_per_m
        self.S = np.array(
            [
                [1.0, sq["xy"] * 1e-6, sq["xz"] * 1e-6],
                [0.0, 1.0, sq["yz"] * 1e-6],
                [0.0, 0.0, 1.0],
            ]
        )
        self.nozzle = np.array([params.nozzle_offset_mm[a] for a in AXES])
        # Per axis: translation polys (mm per mm**k), rotation polys (rad per mm**k).
        self._t = []
        self._r = []
        max_t_deg = 0
        max_r_deg = 0
        for i, a in enumerate(AXES):
            terms = params.axis_errors[a]
            t_polys = []
            for j, name in enumerate(("tx_um", "ty_um", "tz_um")):
                c = [v * 1e-3 for v in terms[name]]  # um -> mm
                if j == i:  # scale: linear positioning error along the own axis
                    while len(c) < 2:
                        c.append(0.0)
                    c[1] += params.scale_ppm[a] * 1e-6
                t_polys.append(tuple(c))
                max_t_deg = max(max_t_deg, _degree(c))
            r_polys = []
            for name in ("rx_urad", "ry_urad", "rz_urad"):
                c = tuple(v * 1e-6 for v in terms[name])  # urad -> rad
                r_polys.append(c)
                max_r_deg = max(max_r_deg, _degree(c))
            self._t.append(tuple(t_polys))
            self._r.append(tuple(r_polys))
        self._has_rotation = any(any(v != 0.0 for v in c) for rp in self._r for c in rp)

        if self.kinematics == "parallel":
            affine = max_t_deg <= 1 and max_r_deg <= 1
        else:
            affine = max_t_deg <= 1 and max_r_deg == 0
        self.is_affine = affine

        # Affine part: exact when is_affine, a linearisation at the origin otherwise.
        origin = self._forward_many(np.zeros((1, 3)))[0]
        cols = self._forward_many(np.eye(3))
        self.A = (cols - origin).T  # A[:, j] = f(e_j) - f(0)
        self.b = origin
        self.A_inv = np.linalg.inv(self.A)
        self.is_identity = bool(affine and np.array_equal(self.A, np.eye(3)) and not np.any(self.b))
        self.is_translation = bool(affine and np.array_equal(self.A, np.eye(3)))
        # Plain-Python copies for the per-move hot path and the accelerated engines:
        # q = inverse_rows (p - offset_mm) for affine models.
        self._A_rows = tuple(tuple(float(v) for v in row) for row in self.A)
        self.offset_mm = tuple(float(v) for v in self.b)
        self.inverse_rows = tuple(tuple(float(v) for v in row) for row in self.A_inv)
        self.coupling = self._coupling()

    # -- structure ---------------------------------------------------------------------
    def _coupling(self):
        """coupling[k][j]: output axis k depends on input axis j (k != j)."""
        if self.is_affine:
            J = self.A
            return tuple(tuple(k != j and J[k, j] != 0.0 for j in range(3)) for k in range(3))
        dep = [[False] * 3 for _ in range(3)]
        rng = np.random.default_rng(12345)
        for p in rng.uniform(-300, 300, size=(4, 3)):
            J = self.jacobian(p)
            for k in range(3):
                for j in range(3):
                    if k != j and abs(J[k, j]) > 1e-15:
                        dep[k][j] = True
        return tuple(tuple(r) for r in dep)

    def jacobian(self, p: Sequence[float], h: float = 1e-3) -> np.ndarray:
        """d actual / d commanded at p (central differences, 3x3)."""
        p = np.asarray(p, dtype=float)
        pts = np.vstack([p + h * np.eye(3), p - h * np.eye(3)])
        f = self._forward_many(pts)
        return ((f[:3] - f[3:]) / (2 * h)).T

    # -- forward -----------------------------------------------------------------------
    def _axis_terms(self, i: int, q: np.ndarray):
        t = np.stack([_poly_eval(c, q) for c in self._t[i]], axis=-1)
        r = np.stack([_poly_eval(c, q) for c in self._r[i]], axis=-1)
        return t, r

    def _forward_many(self, P: np.ndarray) -> np.ndarray:
        P = np.asarray(P, dtype=float)
        n = self.nozzle
        if self.kinematics == "parallel":
            acc = P.copy()
            for i in range(3):
                t, r = self._axis_terms(i, P[:, i])
                acc += t
                if self._has_rotation:
                    acc += np.cross(r, n)  # (R - I) n for small angles
        else:
            v = np.broadcast_to(n, P.shape).copy()
            for a in reversed(CHAINS[self.kinematics]):
                i = AXES.index(a)
                t, r = self._axis_terms(i, P[:, i])
                if self._has_rotation:
                    v = v + np.cross(r, v)
                v = v + t
                v[:, i] += P[:, i]
            acc = v - n
        return acc @ self.S.T

    def forward_many(self, P) -> np.ndarray:
        """Vectorised forward map: (N, 3) commanded -> (N, 3) actual, mm."""
        P = np.asarray(P, dtype=float)
        if self.is_affine:
            return P @ self.A.T + self.b
        return self._forward_many(P)

    def forward(self, p: Sequence[float]) -> Vec:
        """Commanded machine position (mm) -> actual nozzle position (mm)."""
        if self.is_affine:
            A, b = self._A_rows, self.offset_mm
            x, y, z = p
            return (
                A[0][0] * x + A[0][1] * y + A[0][2] * z + b[0],
                A[1][0] * x + A[1][1] * y + A[1][2] * z + b[1],
                A[2][0] * x + A[2][1] * y + A[2][2] * z + b[2],
            )
        return tuple(float(v) for v in self._forward_many(np.asarray([p], dtype=float))[0])

    # -- inverse -----------------------------------------------------------------------
    def inverse(self, d: Sequence[float]) -> Vec:
        """Desired position (mm) -> command (mm) with ``forward(command) == d`` to 1e-9 mm.

        Affine models are inverted exactly; others by a fixed-point iteration on the exact
        forward map preconditioned with the inverse linearisation (the paper's first-order
        "add the error" is only its first step).
        """
        Ai, b = self.inverse_rows, self.offset_mm
        x, y, z = d[0] - b[0], d[1] - b[1], d[2] - b[2]
        q = (
            Ai[0][0] * x + Ai[0][1] * y + Ai[0][2] * z,
            Ai[1][0] * x + Ai[1][1] * y + Ai[1][2] * z,
            Ai[2][0] * x + Ai[2][1] * y + Ai[2][2] * z,
        )
        if self.is_affine:
            return q
        qa = np.array(q)
        da = np.asarray(d, dtype=float)
        for _ in range(INVERSE_MAX_ITER):
            r = self._forward_many(qa[None, :])[0] - da
            if float(np.max(np.abs(r))) < INVERSE_TOL_MM:
                return tuple(float(v) for v in qa)
            qa = qa - self.A_inv @ r
        raise InverseError(f"inverse did not converge at {tuple(d)}")

    def inverse_many(self, D) -> np.ndarray:
        """Vectorised inverse: (N, 3) desired -> (N, 3) commands, mm."""
        D = np.asarray(D, dtype=float)
        Q = (D - self.b) @ self.A_inv.T
        if self.is_affine:
            return Q
        for _ in range(INVERSE_MAX_ITER):
            R = self._forward_many(Q) - D
            if float(np.max(np.abs(R), initial=0.0)) < INVERSE_TOL_MM:
                return Q
            Q = Q - R @ self.A_inv.T
        raise InverseError("inverse did not converge")


def _degree(coeffs) -> int:
    deg = 0
    for k, c in enumerate(coeffs):
        if c != 0.0:
            deg = k
    return deg


def changes_nothing(params: Params) -> bool:
    """True when compensating with ``params`` changes nothing: the model is the identity and
    neither backlash nor servo pre-compensation is active (the output must equal the input)."""
    return (
        KinematicModel(params).is_identity
        and not params.has_backlash
        and not params.has_servo_precomp
    )
