"""The condensed QP of the MPC with servo mechanism (section 3.2, Eq. (15)-(19)).

Condensed QP
------------
Let ``D = [Delta u_c(k|k), ..., Delta u_c(k+Hu-1|k)]`` and the data vector
``z = [l(k), l(k-1), u_c(k-1), x_s(k), r(k), ..., r(k+Hp)]``.  With the impulse
response ``h_n = C A^n B`` and step response ``s_i = sum_{n<i} h_n``::

    l_hat(k+i|k) = C A^i x(k) + s_i u_c(k-1) + sum_{m<min(i,Hu)} s_{i-m} D_m
    L   = F z + G D                      (Hp predictions, G[i-1, m] = s_{i-m})
    X_s = S0 z - N D,   N = M G          (M: strictly lower-triangular ones; not Eq. (5)'s H)

so ``J = 0.5 D^T P D + (K z)^T D + const`` with
``P = 2 (G^T Q G + R + N^T Qs N)`` and ``K = 2 (G^T Q E0 - N^T Qs S0)``
(``E0 = F - [r(k+1..k+Hp) selector]``).  Internally Eq. (15) is kept as the
sum of squares of the stacked residual ``[E0 z + G D; S0 z - N D; D]`` with
rows scaled by ``sqrt([Q; Qs; R])``, from which ``P``, ``K`` (as Gram blocks)
and the cost are formed.  One matrix ``B`` maps ``[D; z]`` to that residual
followed by the predictions ``L``, ``X_s`` and the input plan, so cost,
predictions and plan of any moves are one matrix-vector product.  ``B`` is
affine in the step response and the rows ``C A^n``; that map is tabulated at
construction, so a new model costs one matrix-vector product for ``B`` (only
its model-dependent entries are rewritten, in place), one small matrix product
for ``P``, ``K`` and one Cholesky solve for ``-P^{-1} K``. For long horizons
(a map of more than :data:`MAX_TABULATED` entries) ``B`` is formed from the step
response directly instead.
The constraint matrix is the cumulative-sum matrix ``S`` (``u_c(k+i|k) =
u_c(k-1) + (S D)_i``).  ``P`` and ``K`` depend on ``(a1, a2, b1)`` only, ``S``
never changes.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg.lapack import dposv as _dposv

__all__ = ["CondensedServoQP", "MAX_TABULATED"]

#: Largest tabulated map ``T`` [entries] (:class:`CondensedServoQP`): beyond it (Hp = Hu of 17 and
#: more, Hp of 22 and more at Hu = 5) ``B`` is formed from the model's step response directly, which
#: sums in another order: results there differ from the tabulated map's by about 1e-12 relative.
MAX_TABULATED = 200_000


class CondensedServoQP:
    """Eq. (15)'s residual map ``B`` and the QP matrices for a model ``(a1, a2, b1)``.

    Built once per horizon and weights (the constructor tabulates ``B`` as an affine map of the
    model's step response); :meth:`set_model` then rewrites only the model-dependent entries of
    ``B`` in place and solves the normal equations for the unconstrained minimiser.

    Parameters
    ----------
    hp, hu : int
        Prediction and control horizons (Table 5: 5, 5).
    Q, Qs, R : ndarray
        Weights of Eq. (15) per step: tracking error (``Hp``), integrator state (``Hp``),
        input moves (``Hu``) [1/mm^2, 1/mm^2, 1/V^2].
    """

    def __init__(self, hp: int, hu: int, Q: np.ndarray, Qs: np.ndarray, R: np.ndarray) -> None:
        self.hp, self.hu = hp, hu
        nz = self.nz = 4 + hp + 1  # z = [l, l_prev, uc_prev, xs, r(k..k+Hp)]
        nres = self.nres = 2 * hp + hu  # residual rows of Eq. (15)
        S = np.tril(np.ones((hu, hu)))  # u_c(k+i) = uc_prev + (S D)_i (Eq. (20))
        # The stacked matrix B maps v = [D; z] (Hu moves, then the nz data) to
        #   rows 0..Hp-1           sqrt(Q)  (l_hat(k+i|k) - r(k+i)),  i = 1..Hp
        #   rows Hp..2Hp-1         sqrt(Qs) x_s(k+i|k),               i = 1..Hp
        #   rows 2Hp..2Hp+Hu-1     sqrt(R)  D
        #   rows 2Hp+Hu..          l_hat(k+i|k), then x_s(k+i|k)      (predictions)
        #   last Hu rows           u_c(k+i|k) = u_c(k-1) + (S D)_i    (input plan)
        # so Eq. (15) is |first nres rows of B v|^2 and P/2, K/2 are Gram blocks.
        # Unweighted, B = B0 + Lmap @ [G | F]; the model enters only through
        # [G | F] (Hp rows), whose entries are taken from
        # x = [s_1..s_Hp, p_1..p_Hp, q_1..q_Hp] (step response, rows C A^n).
        c = hu  # first z column
        B0 = np.zeros((nres + 2 * hp + hu, hu + nz))
        B0[np.arange(hp), c + 5 + np.arange(hp)] = -1.0            # - r(k+i)
        B0[hp:2 * hp, c + 0] = -1.0                                 # - l(k|k)
        B0[hp:2 * hp, c + 3] = 1.0                                  # + x_s(k)
        B0[hp:2 * hp, c + 4:c + 4 + hp] = np.tril(np.ones((hp, hp)))  # + r(k..k+i-1)
        B0[2 * hp:nres, :hu] = np.eye(hu)                           # + D
        B0[nres + hp:nres + 2 * hp] = B0[hp:2 * hp]                 # x_s again, unweighted
        B0[nres + 2 * hp:, :hu] = S                                 # u_c(k-1) + S D
        B0[nres + 2 * hp:, c + 2] = 1.0
        # Lmap = [I; -M; 0; I; -M; 0] (M strictly lower-triangular ones: x_s(k+i) sums
        # l_hat(k+1..k+i-1)), applied by its blocks (_unweighted)
        # [G | F] = [0, x][gf_idx]: G[i-1, m] = s_{max(i-m, 0)} (s_0 = 0),
        # F[i-1, :3] = [p_i, q_i, s_i], other columns of F zero
        gf_idx = np.zeros((hp, hu + nz), dtype=np.intp)
        i, m = np.meshgrid(np.arange(1, hp + 1), np.arange(hu), indexing="ij")
        gf_idx[:, :hu] = np.maximum(i - m, 0)
        gf_idx[:, c + 0] = hp + np.arange(1, hp + 1)
        gf_idx[:, c + 1] = 2 * hp + np.arange(1, hp + 1)
        gf_idx[:, c + 2] = np.arange(1, hp + 1)

        self._B0, self._gf_idx = B0, gf_idx
        self._row_scale = np.concatenate([np.sqrt(Q), np.sqrt(Qs), np.sqrt(R), np.ones(2 * hp + hu)])
        self._T: np.ndarray | None = None
        # B is affine in x: tabulated once (exact: integer entries), a model update is a single
        # matrix-vector product, B = T @ [x; 1]. T has (3 Hp + 1) times B's entries: 7,200 for
        # Table 5, 4.7 million (38 MB, 115 MB at its peak while built, 1.1 s) at Hp = Hu = 50,
        # where B is formed from x directly instead.
        self.tabulated = B0.size * (3 * hp + 1) <= MAX_TABULATED
        if self.tabulated:
            T = self.T
            # Most entries of B do not depend on the model (104 of 450 for Table 5): keep B as
            # one buffer holding the constant ones and rewrite only the rows of T that have a
            # model coefficient (the same row-times-[x; 1] products, ~2x cheaper than all of T).
            self._B_var = np.flatnonzero(np.any(T[:, :-1] != 0.0, axis=1))
            self._T_var = np.ascontiguousarray(T[self._B_var])
            self._B = T[:, -1].reshape(B0.shape).copy()  # x = 0: the constant entries
        else:
            self._B = self._weighted(np.zeros(3 * hp))
        self._B_flat = self._B.reshape(-1)  # a view: writes go to self._B

        self.gram: np.ndarray | None = None  # [P/2 | K/2], the Gram blocks of the weighted residual
        self.K_unc: np.ndarray | None = None
        self._P: np.ndarray | None = None
        self._K: np.ndarray | None = None

    def _unweighted(self, x: np.ndarray) -> np.ndarray:
        """Unweighted ``B`` for ``x = [s_1..s_Hp, p_1..p_Hp, q_1..q_Hp]``: ``B0 + Lmap [G | F]``."""
        gf = np.concatenate([[0.0], x])[self._gf_idx]
        # Lmap's blocks: M a shifted running sum, no matrix product (which a multi-threaded BLAS
        # makes a hundred times slower on a busy machine)
        summed = np.zeros_like(gf)
        np.cumsum(gf[:-1], axis=0, out=summed[1:])
        zeros = np.zeros((self.hu, gf.shape[1]))
        return self._B0 + np.concatenate([gf, -summed, zeros, gf, -summed, zeros])

    def _weighted(self, x: np.ndarray) -> np.ndarray:
        """``B`` for ``x``, formed directly: :meth:`_unweighted` with the rows weighted."""
        return self._unweighted(x) * self._row_scale[:, None]

    @property
    def T(self) -> np.ndarray:
        """The tabulated affine map: ``B.ravel() = T @ [s_1..s_Hp, p_1..p_Hp, q_1..q_Hp, 1]`` (built
        on first use where :attr:`tabulated` is False)."""
        if self._T is None:
            nx = 3 * self.hp
            base = self._unweighted(np.zeros(nx))
            cols = [(self._unweighted(e) - base).ravel() for e in np.eye(nx)] + [base.ravel()]
            self._T = np.stack(cols, axis=1) * np.repeat(self._row_scale, self.hu + self.nz)[:, None]
        return self._T

    @property
    def B(self) -> np.ndarray:
        """``B`` (module docstring): ``B [D; z]`` = weighted residual, predictions, input plan."""
        return self._B

    @property
    def G_weighted(self) -> np.ndarray:
        """Weighted residual rows of ``B``, move columns."""
        return self._B[:self.nres, :self.hu]

    @property
    def W_weighted(self) -> np.ndarray:
        """Weighted residual rows of ``B``, data columns."""
        return self._B[:self.nres, self.hu:]

    def set_model(self, a1: float, a2: float, b1: float) -> None:
        """Condensed matrices of the module docstring for ``(a1, a2, b1)`` (numpy only).

        Parameters
        ----------
        a1, a2, b1 : float
            Eq. (2)'s predictor (finite, ``|b1| > 0``; the caller checks).
        """
        hp, hu, nres = self.hp, self.hu, self.nres
        # rows C A^n = [p_n, q_n] by [p, q] A = [a1 p + q, a2 p]; impulse
        # response h_n = C A^n B = b1 p_n, step response s_n = sum_{m<n} h_m
        x = [0.0] * (3 * hp + 1)  # [s_1..s_Hp, p_1..p_Hp, q_1..q_Hp, 1]
        x[-1] = 1.0
        p, q, s = 1.0, 0.0, 0.0
        for n in range(hp):
            s += b1 * p
            p, q = a1 * p + q, a2 * p
            x[n] = s
            x[hp + n] = p
            x[2 * hp + n] = q
        # B = T [x; 1] (reshaped), in place: only the model-dependent entries change.
        # Nothing keeps a view of the old B (results hold products of it, not views).
        B = self._B
        if self.tabulated:
            self._B_flat[self._B_var] = self._T_var.dot(x)
        else:
            B[...] = self._weighted(np.array(x[:-1]))
        # [P/2 | K/2] = Gall^T [Gall | W] with [Gall | W] the weighted residual rows
        Gall = B[:nres, :hu]
        gram = Gall.T.dot(B[:nres])
        # unconstrained minimiser D* = -P^{-1} K z; P is SPD (R > 0): Cholesky
        _, X, info = _dposv(gram[:, :hu], gram[:, hu:])
        if info != 0:  # not numerically positive definite: general LU solve
            X = np.linalg.solve(gram[:, :hu], gram[:, hu:])
        self.K_unc = np.negative(X)
        self.gram = gram
        self._P = self._K = None  # OSQP-path matrices, built on demand by matrices()


    def matrices(self) -> tuple[np.ndarray, np.ndarray]:
        """``(P, K)`` of the module docstring for the current model (cached until the next model)."""
        if self._P is None:
            Ph = self.gram[:, :self.hu]
            self._P = Ph + Ph.T                    # = 2 * sym(P/2), bit-symmetric for OSQP
            self._K = 2.0 * self.gram[:, self.hu:]
        return self._P, self._K
