"""The fixed predictor of section 4.2 ("a preliminary identification under 44 N"), as numbers.

:data:`THETA0_44N` is what :func:`tapmuscle.paper.preliminary_theta` (seed 0, refinement at 0.05 Hz)
returns on the simulated rig with the default plant parameters (on the machine it was generated on: the
identification ends in a closed loop, so another CPU's rounding gives another, equally good estimate).
It is the default ``theta0`` of the ``AMPCController`` FMU, which must not depend on the plant to start.
``tests/test_paper.py`` identifies again and fails when this table predicts the plant worse than the new
estimate does; the plant then changed, and this table is regenerated with::

    python -c "from tapmuscle.paper import preliminary_theta; print(preliminary_theta(0, refine_hz=0.05).tolist())"
"""

from __future__ import annotations

__all__ = ["THETA0_44N", "THETA0_LIMIT", "REFINE_IN_CLOSED_LOOP"]

#: How a fixed predictor is made for a rig, in the words the controllers' messages use.
REFINE_IN_CLOSED_LOOP = "refine a fixed model in closed loop (docs/python-api.md, tapmuscle.paper.preliminary_theta)"

#: Eq. (1) parameters in :data:`fmu_controller.hysteresis_model.ASYMMETRIC` order
#: (a1, a2, b1, A1, A2, beta1, beta2, gamma1, gamma2, c1, c2, xi21, xi22, xi31, xi32); l in mm, u in V.
THETA0_44N: tuple[float, ...] = (
    1.208, -0.33397620375869924, 0.8051173008818517, -0.015490430685319235, -0.013541752244599718,
    -0.03332317504810225, -0.009307750752229687, -0.034156121547728756, -0.02021089527360774,
    0.16793763657309427, -0.09626804784864249, 0.009891619048288652, -0.007771726607492789,
    -0.00012439677162588104, 0.00010686574930884236,
)

#: Largest |theta0.*|: Eq. (1)'s coefficients multiply displacements [mm] and commands [V]; a
#: preliminary identification's are below 2 (THETA0_44N), and beyond this the predictions over the
#: horizon overflow floating point instead of failing a check that names the parameter (the
#: controller FMU's declared range of ``theta0.*``; an identification file's ``theta`` is held to it).
THETA0_LIMIT = 1e6
