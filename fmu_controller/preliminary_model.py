"""The fixed predictor of section 4.2 ("a preliminary identification under 44 N"), as numbers.

:data:`THETA0_44N` is what :func:`tapmuscle.paper.preliminary_theta` (seed 0, refinement at 0.05 Hz)
returns on the simulated rig with the default plant parameters. It is the default ``theta0`` of the
``AMPCController`` FMU, which must not depend on the plant to start. ``tests/test_paper.py`` recomputes
it and fails if the plant changed and this table was not regenerated with::

    python -c "from tapmuscle.paper import preliminary_theta; print(preliminary_theta().tolist())"
"""

from __future__ import annotations

__all__ = ["THETA0_44N"]

#: Eq. (1) parameters in :data:`fmu_controller.hysteresis_model.ASYMMETRIC` order
#: (a1, a2, b1, A1, A2, beta1, beta2, gamma1, gamma2, c1, c2, xi21, xi22, xi31, xi32); l in mm, u in V.
THETA0_44N: tuple[float, ...] = (
    1.208, -0.33398148748003564, 0.8127122742874707, 0.027086138889180236, -0.0893712090913352,
    -0.024710937581994222, -0.012944327215356434, -0.016291267280429057, 0.008288093409022578,
    0.10745133089179623, -0.0206253954096758, 0.008626489365167777, -0.006509164315177743,
    -0.00011217764682172866, 9.414911509358463e-05,
)
