"""The rig's equations fused for speed, and their integrator: ROS34PW2 sub-steps.

:func:`build_model` returns plain-float closures of the right-hand side (the equations of
:mod:`fmu_plant.equations`, inlined: no function calls or attribute look-ups in the hot path), the
entries of its Jacobian the Rosenbrock-W scheme uses, one sub-step, and the adaptive sub-steps over
one communication step with their step-size controller. ``tests/test_equations.py`` checks the
closures against the one definition.
"""

from __future__ import annotations

import importlib
import math
import os
from importlib.machinery import EXTENSION_SUFFIXES
from types import ModuleType
from typing import Any, Callable, Iterable

from .muscle import LOCK_EXPONENT_MAX, MuscleGeometry
from .parameters import CV_TO_SI_WATER, GRAVITY_M_S2, PlantParams

__all__ = ["build_model", "compiled_step_loop", "forced_substeps", "COMPILED", "COMPILED_FOR_ANOTHER_PYTHON", "SAFETY", "GROWTH", "SHRINK",
           "ERR_FLOOR", "STRETCH",
           "KINK_SCALE_INITIAL", "KINK_FLOOR", "FORCED_MAX", "adaptive_steps"]


#: Where the compiled sub-step lies (this file's folder), and whether it is asked away.
_HERE = os.path.dirname(os.path.abspath(__file__))
_PURE_PYTHON = os.environ.get("TAPMUSCLE_PURE_PYTHON") == "1"


def _compiled_module() -> ModuleType | None:
    """The sub-step compiled from ``_ros34pw2.c`` (setup.py) if it was built beside this file.

    Only beside this file: an FMU carries the one built for its building interpreter (or none), and
    a host whose path reaches a checkout with a build of its own (an editable install's import
    finder does) must not load that one into the FMU's code. ``TAPMUSCLE_PURE_PYTHON=1`` asks for
    the Python sub-step (the same bits, slower).
    """
    if _PURE_PYTHON or not any(os.path.isfile(os.path.join(_HERE, "_ros34pw2" + suffix)) for suffix in EXTENSION_SUFFIXES):
        return None
    try:
        return importlib.import_module("._ros34pw2", __package__)
    except ImportError:  # built for another interpreter: the closure below, same bits
        return None


_ros34pw2 = _compiled_module()

#: Whether :func:`build_model` can return the compiled sub-step (``fmu_plant/_ros34pw2.c``).
COMPILED = _ros34pw2 is not None


def _compiled_for_another_python() -> str | None:
    """The compiled sub-step's file beside this one when it is another interpreter's (an FMU built by
    CPython 3.11 in a 3.13 host), which this one cannot load: the Python sub-step runs instead."""
    if COMPILED or _PURE_PYTHON:
        return None
    found = sorted(f for f in os.listdir(_HERE) if f.startswith("_ros34pw2.") and f.endswith((".so", ".pyd")))
    return found[0] if found else None


#: The compiled sub-step shipped beside this file for another interpreter (None: none, or it is in use).
COMPILED_FOR_ANOTHER_PYTHON = _compiled_for_another_python()


# ---------------------------------------------------------------------------------------- solver
# ROS34PW2 (Rang & Angermann, BIT 45 (2005) 761-787): a 4-stage, 3rd-order, L-stable, stiffly
# accurate Rosenbrock-W method with an embedded 2nd-order solution. "W": it keeps its order with any
# approximation of the Jacobian, so the stiff part alone is enough and the non-autonomous spool
# input x(t) needs no time derivative. Published form: stage table alpha, Gamma (diagonal gamma),
# weights b and b_hat; below transformed (Hairer & Wanner, Solving ODEs II, IV.7) so that a stage
# needs one linear solve and no Jacobian-vector product:
#     (I - gamma h J) U_i = gamma h f(t0 + c_i h, y0 + sum_j A_ij U_j) + sum_j GC_ij U_j,
#     y1 = y0 + sum_i M_i U_i,   error estimate sum_i E_i U_i.
_ROS_GAMMA = 0.435866521508459
_ROS_ALPHA = ((0.0, 0.0, 0.0), (0.87173304301691801, 0.0, 0.0),
              (0.84457060015369423, -0.11299064236484185, 0.0), (0.0, 0.0, 1.0))
_ROS_GAMMA_OFF = ((0.0, 0.0, 0.0), (-0.87173304301691801, 0.0, 0.0),
                  (-0.90338057013044082, 0.054180672388095326, 0.0),
                  (0.24212380706095346, -1.2232505839045147, 0.54526025533510214))
_ROS_B = (0.24212380706095346, -1.2232505839045147, 1.5452602553351020, 0.435866521508459)
_ROS_B_HAT = (0.37810903145819369, -0.096042292212423178, 0.5, 0.2179332607542295)


def _sum(terms: Iterable[float]) -> float:
    """Left-to-right float sum. The built-in ``sum`` compensates rounding since Python 3.12, which
    moved the coefficients below, and so every plant output, by a last bit between Python versions;
    this one gives the same coefficients on every version."""
    total = 0.0
    for term in terms:
        total += term
    return total


def _ros_transformed() -> tuple[list[list[float]], list[list[float]], list[float], list[float], list[float]]:
    """``(A, GC, M, E, c)`` of the transformed ROS34PW2 scheme (see the comment above)."""
    s, g = 4, _ROS_GAMMA
    gam = [[(_ROS_GAMMA_OFF[i][j] if j < i else g if j == i else 0.0) for j in range(s)] for i in range(s)]
    inv = [[0.0] * s for _ in range(s)]  # inverse of the lower-triangular Gamma, by forward substitution
    for col in range(s):
        for i in range(s):
            acc = (1.0 if i == col else 0.0) - _sum(gam[i][k] * inv[k][col] for k in range(i))
            inv[i][col] = acc / gam[i][i]
    alpha = [[(_ROS_ALPHA[i][j] if j < i else 0.0) for j in range(s)] for i in range(s)]
    a = [[_sum(alpha[i][k] * inv[k][j] for k in range(s)) for j in range(s)] for i in range(s)]
    gc = [[g * ((1.0 / g if i == j else 0.0) - inv[i][j]) for j in range(s)] for i in range(s)]
    m = [_sum(_ROS_B[k] * inv[k][j] for k in range(s)) for j in range(s)]
    e = [m[j] - _sum(_ROS_B_HAT[k] * inv[k][j] for k in range(s)) for j in range(s)]
    c = [_sum(row) for row in alpha]
    return a, gc, m, e, c


_A, _GC, _M, _E, _C = _ros_transformed()


#: Step-size control (Hairer & Wanner's standard controller for an embedded order-2 estimate).
SAFETY = 0.9
GROWTH = 2.0   # largest step growth from one sub-step to the next
SHRINK = 0.2   # largest step reduction after a rejected sub-step
ERR_FLOOR = (SAFETY / GROWTH) ** 3  # errors below this allow the largest growth
STRETCH = 1.25  # the last sub-step of a communication step may exceed the proposal by this factor
_CROSS_ERR = 2.0  # error given to a sub-step whose stages reverse the motion spuriously (shrinks it by 0.7)
_CROSS_MIN_H = 1e-4  # [s] below this a spurious stage reversal is accepted (it moves z by ~ |v| h)

#: Sub-steps of ``solver.min_substep_s`` accepted over their tolerances (to get past a kink) that one
#: communication step may take: this many, or ``dt / max_substep_s`` if more. Beyond that the
#: tolerances cannot be met at all (stiff/extreme parameters): ``FloatingPointError`` rather than a
#: long run of inaccurate sub-steps. Without a floor on the proposals such parameters (a presliding
#: length of 1e-9 mm) would settle the step size at 1e-10 s, and a communication step would never end.
FORCED_MAX = 1000

#: First sub-step of a communication step: ``h = kink_scale / |change of spool target|^(1/3)``.
KINK_SCALE_INITIAL = 0.004  # [s] after :meth:`Plant.reset` (5 ms for a first command of 5 V)
KINK_FLOOR = 1e-3  # changes below this count as this (no change: a long first step)


def _loop_constants(prm: PlantParams) -> dict[str, float]:
    """The constants of the loop of sub-steps, by the names the compiled model takes them under."""
    vp, sol = prm.valve, prm.solver
    return {"u_min": vp.u_min_v, "u_span": vp.u_max_v - vp.u_min_v, "h_max": sol.max_substep_s,
            "h_min": sol.min_substep_s, "safety": SAFETY, "growth": GROWTH, "shrink": SHRINK,
            "err_floor": ERR_FLOOR, "stretch": STRETCH, "kink_floor": KINK_FLOOR, "forced_max": float(FORCED_MAX)}


def adaptive_steps(attempt: Callable[..., tuple[float, ...]], prm: PlantParams) -> Callable[..., tuple[float, ...]]:
    """The ``advance`` of :func:`build_model` (its docstring) around the sub-step ``attempt``, in Python.

    The compiled ``advance`` is this loop, operation for operation (and the same error message); a
    benchmark passes a counting ``attempt`` here to see the sub-steps.

    Its work is bounded: no sub-step is shorter than ``h_min`` (``solver.min_substep_s``) but those
    that end the communication step (the last one, or the halved rest), and one of ``h_min`` is
    accepted whatever its error, so a step takes at most about ``dt / h_min`` sub-steps (between two
    of them a bounded number of rejections, each shrinking the step by 10 % or more); more than
    ``max(FORCED_MAX, dt / h_max)`` sub-steps accepted over their tolerances raise
    ``FloatingPointError``.

    Parameters
    ----------
    attempt : callable
        The sub-step, ``attempt(x, p, l, v, z, xs, ps, w, h) -> (x, p, l, v, z, err)``
        (:func:`build_model`'s ``attempt``): ``err`` <= 1 accepts it; an ``OverflowError`` counts
        as an infinite error.
    prm : PlantParams
        The plant's parameters: the valve's command range [V] and the solver's ``max_substep_s``
        and ``min_substep_s`` [s].
    """
    c = _loop_constants(prm)
    u_min, u_span, h_max, h_min = c["u_min"], c["u_span"], c["h_max"], c["h_min"]
    forced_max_floor = c["forced_max"]
    inf = math.inf
    forced_total = [0]  # sub-steps accepted over their tolerances since the loop was built (forced_substeps)

    def advance(x, p, l, v, z, xs_last, kink_scale, last_ps, u, ps, w, t0, dt, ports):
        x0, p0, l0, v0, z0 = x, p, l, v, z
        if ports is None:
            xs = (u - u_min) / u_span
            xs = 0.0 if xs < 0.0 else 1.0 if xs > 1.0 else xs
        else:
            xs = xs_last
        done = 0.0
        left = dt
        h_try = 0.0  # set with the first sub-step's command below
        first = True
        sampled = False
        retry = False  # after a rejection the step must shrink (no stretching)
        forced = 0  # sub-steps accepted at the shortest sub-step although over their tolerances
        forced_max = dt / h_max
        if forced_max < forced_max_floor:
            forced_max = forced_max_floor
        while True:
            if ports is not None and not sampled:  # once per sub-step, also when it is retried
                u, ps, w = ports(t0 + done)
                xs = (u - u_min) / u_span
                xs = 0.0 if xs < 0.0 else 1.0 if xs > 1.0 else xs
                sampled = True
            if first and not retry:
                # The first sub-step after a command change resolves the spool's kink; its error
                # grows with the change, roughly as |change| h^3: scale the remembered proposal.
                kink = xs - xs_last
                kink = kink if kink > KINK_FLOOR else -kink if -kink > KINK_FLOOR else KINK_FLOOR
                kink_root = kink ** (1.0 / 3.0)
                h_try = kink_scale / kink_root
            if h_try > h_max:
                h_try = h_max
            if not h_try >= h_min:  # never propose less than the shortest sub-step (nor NaN)
                h_try = h_min
            # End exactly on the communication point: stretch the step a little rather than leave
            # a short remainder, or split the rest in two.
            if left <= (h_try if retry else STRETCH * h_try):
                h, last = left, True
            elif left < 2.0 * h_try:
                h, last = 0.5 * left, False
            else:
                h, last = h_try, False
            try:
                new = attempt(x, p, l, v, z, xs, ps, w, h)
                err = new[5]
            except OverflowError:  # a float power beyond range, where the compiled sub-step's pow gives inf
                err = inf
            if err <= 1.0 or h <= h_min:
                if not err < inf:  # NaN or inf at the shortest step: the numbers broke down
                    return x0, p0, l0, v0, z0, xs_last, kink_scale, last_ps, t0 + done
                if err > 1.0:  # accepted only for being the shortest sub-step
                    forced += 1
                    forced_total[0] += 1
                    if forced > forced_max:
                        raise FloatingPointError(
                            f"plant integration failed at t = {t0 + done:.6g} s: too many sub-steps of "
                            f"solver.min_substep_s = {h_min:.6g} s over their error tolerances in one "
                            f"communication step ({forced}): stiff/extreme parameters? (a smaller "
                            f"min_substep_s may help)")
                x, p, l, v, z = new[0], new[1], new[2], new[3], new[4]
                if l < 0.0:  # the stop is rigid: no penetration, no rebound
                    l = 0.0
                    if v < 0.0:
                        v = 0.0
                fac = SAFETY * err ** (-1.0 / 3.0) if err > ERR_FLOOR else GROWTH
                if fac > GROWTH:
                    fac = GROWTH
                h_next = h * fac
                if first:
                    if not last or fac < 1.0 or h_next * kink_root > kink_scale:
                        kink_scale = h_next * kink_root
                    first = False
                last_ps = ps
                if last:
                    return x, p, l, v, z, xs, kink_scale, last_ps, math.nan
                done += h
                left = dt - done
                h_try = h_next
                sampled = retry = False
            else:
                fac = SAFETY * err ** (-1.0 / 3.0)
                h_try = h * (fac if fac > SHRINK else SHRINK)
                retry = True

    advance.forced_total = forced_total
    return advance


def forced_substeps(advance: Callable[..., tuple[float, ...]]) -> int:
    """How many sub-steps of ``solver.min_substep_s`` the ``advance`` of :func:`build_model` (or of
    :func:`adaptive_steps`) has accepted over their error tolerances since it was built, over every
    call and the compiled step loop's: a run with any is not integrated to the solver's tolerances
    (stiff parameters; a smaller ``min_substep_s`` makes it accurate). 0 for an ``advance`` that keeps
    no count (a benchmark's wrapper).

    Parameters
    ----------
    advance : callable
        The ``advance`` of :func:`build_model` or :func:`adaptive_steps`.
    """
    model = getattr(advance, "__self__", None)
    if _ros34pw2 is not None and isinstance(model, _ros34pw2.Model):
        return int(model.forced_substeps)
    cell = getattr(advance, "forced_total", None)
    return 0 if cell is None else int(cell[0])


def compiled_step_loop(advance: Callable[..., tuple[float, ...]]) -> Callable[..., tuple[Any, ...]] | None:
    """The compiled step loop (``Model.run``, ``compiled_run.py``) of the model whose ``advance``
    :func:`build_model` returned, or None for the Python sub-step's.

    Parameters
    ----------
    advance : callable
        The ``advance`` :func:`build_model` returned.
    """
    model = getattr(advance, "__self__", None)
    return model.run if _ros34pw2 is not None and isinstance(model, _ros34pw2.Model) else None


def build_model(prm: PlantParams, *, compiled: bool | None = None
                ) -> tuple[Callable[..., tuple[float, ...]], Callable[..., tuple[float, ...]],
                           Callable[..., tuple[float, ...]], Callable[[float], None], Callable[..., tuple[float, ...]]]:
    """The right-hand side, its Jacobian, the ROS34PW2 sub-step and the adaptive sub-steps over one
    communication step of the rig's equations for ``prm``.

    All are closures over plain-float constants (no attribute lookups or numpy in the hot path). The
    sub-step and the sub-steps' loop may instead be their compiled copies (``fmu_plant/_ros34pw2.c``),
    which do the same IEEE-754 operations in the same order: the same bits, about 30 times faster
    for a sub-step (1 us; ``Plant.step`` several times, ``benchmarks/plant_step_time.py``).

    Parameters
    ----------
    prm : PlantParams
    compiled : bool, optional
        Use the compiled sub-step: ``None`` (default) when it is installed (:data:`COMPILED`), ``False``
        never, ``True`` always (ImportError when it is not installed).

    Returns
    -------
    rhs : callable
        ``rhs(x, p, l, v, z, ps, w, inv_mass) -> (dp/dt, dl/dt, dv/dt, dz/dt)`` in MPa/s, mm/s,
        mm/s^2, N/s; ``ps`` the supply pressure [MPa], ``w`` the load [N], ``inv_mass`` = 1e3 / mass
        [1/kg, scaled to mm]. The spool ``x`` is an input: it is integrated exactly.
    jacobian : callable
        Same arguments; ``rhs`` followed by the Jacobian entries the scheme uses, ``d(dp/dt)/dp,
        d(dp/dt)/dv, d(dp/dt)/dl, d(dv/dt)/dp, d(dv/dt)/dl, d(dv/dt)/dv, d(dv/dt)/dz, d(dz/dt)/dp,
        d(dz/dt)/dv, d(dz/dt)/dz`` (``d(dl/dt)/dv = 1``; the others are small and left out, which a
        W-method allows).
    attempt : callable
        ``attempt(x, p, l, v, z, xs, ps, w, h) -> (x, p, l, v, z, err)``: one sub-step of ``h`` [s] with
        the spool target ``xs`` held; ``err`` the local error estimate relative to the tolerances
        (accept if <= 1). The stop clamp is the caller's.
    set_gate : callable
        ``set_gate(g)``: from now on both valves open ``g`` (0..1) times as far beyond their leak (the
        valve-gate port of effects.py). Rebinding a closure constant keeps the ungated path free.
    advance : callable
        ``advance(x, p, l, v, z, xs_last, kink_scale, last_ps, u, ps, w, t0, dt, ports) -> (x, p, l, v,
        z, xs, kink_scale, last_ps, failed_at)``: the state from ``t0`` to ``t0 + dt`` [s] over adaptive
        sub-steps (docs/plant.md, "Integration"). ``xs_last`` is the spool target of the previous
        communication step and ``kink_scale`` [s] the first sub-step's scale (both carried from one
        call to the next, as is ``last_ps``, the supply pressure [MPa] of the last accepted sub-step).
        ``ports`` is None, with the command ``u`` [V], supply ``ps`` [MPa] and load ``w`` [N] held,
        or ``ports(t) -> (u, ps, w)``, sampled at the start of every sub-step (it may call
        ``set_gate``). ``failed_at`` is NaN, or the time [s] at which the state went non-finite at
        the shortest sub-step; the returned state is then the one at ``t0``. Sub-steps are never
        shorter than ``solver.min_substep_s`` except those ending on ``t0 + dt``, and one that short is
        accepted whatever its error estimate; more than ``max(FORCED_MAX, dt / max_substep_s)`` such
        sub-steps over their tolerances raise ``FloatingPointError`` (naming the time; the caller's
        state is untouched): the work of a call is bounded.
    """
    vp, sup, mp, fp, sol = prm.valve, prm.supply, prm.muscle, prm.friction, prm.solver
    geo = MuscleGeometry.from_params(mp)
    # Valves: Q / C in MPa/s for a drop in MPa, k(x) = K (e + (1 - e) x^n).
    kq = vp.cv_max * CV_TO_SI_WATER * 1e3 / sup.compliance_m3_per_mpa
    kq_leak, kq_open_full = kq * vp.leak_fraction, kq * (1.0 - vp.leak_fraction)
    kq_open = kq_open_full
    n_char = vp.characteristic_exponent
    lam = vp.laminar_dp_mpa
    inv_sqrt_lam = 1.0 / math.sqrt(lam)
    pd = sup.drain_pressure_mpa
    tau = vp.spool_time_constant_s
    # Muscle: A(l) = A0 (a s^2 - b), s = 1 - l / L0; volume rate A v / C in MPa/s for v in mm/s.
    inv_l0 = 1.0 / mp.rest_length_mm
    ga, gb = geo.a, geo.b
    k_area = geo.area0_m2 * 1e-3 / sup.compliance_m3_per_mpa
    k_force = geo.area0_m2 * 1e6  # N per MPa, times (a s^2 - b)
    p_th, w_th = mp.threshold_pressure_mpa, mp.threshold_width_mpa
    inv_w_th = 1.0 / w_th
    f_lock0 = mp.braid_lock_force_n
    inv_lock = 1.0 / mp.braid_lock_length_mm
    k_rubber, damping = mp.rubber_stiffness_n_per_mm, mp.damping_n_s_per_mm
    # Friction.
    cos0, inv_sin0 = geo.cos_alpha0, 1.0 / geo.sin_alpha0
    f0, mu = fp.base_n, fp.per_mpa_n
    up_factor, down_factor = 1.0 + fp.asymmetry, 1.0 - fp.asymmetry
    rate_gain, inv_v_ref, rate_exp = fp.rate_gain, 1.0 / fp.rate_ref_mm_s, fp.rate_exponent
    inv_delta = 1.0 / fp.presliding_mm
    # Error weights.
    inv_tol_p, inv_tol_l = 1.0 / sol.tol_p_mpa, 1.0 / sol.tol_l_mm
    inv_tol_v, inv_tol_z = 1.0 / sol.tol_v_mm_s, 1.0 / sol.tol_z_n
    sqrt, exp, log1p, inf = math.sqrt, math.exp, math.log1p, math.inf
    (_, _, _, _), (a21, _, _, _), (a31, a32, _, _), (a41, a42, a43, _) = _A
    (_, _, _, _), (c21, _, _, _), (c31, c32, _, _), (c41, c42, c43, _) = _GC
    e1, e2, e3, e4 = _E
    _, t2, t3, t4 = _C
    gamma = _ROS_GAMMA
    m_moving = prm.load.moving_mass_kg

    def rhs(x, p, l, v, z, ps, w, inv_mass):
        xc = 0.0 if x < 0.0 else 1.0 if x > 1.0 else x
        k_in = kq_leak + kq_open * xc ** n_char
        k_out = kq_leak + kq_open * (1.0 - xc) ** n_char
        d = ps - p
        if d >= lam:
            q = k_in * sqrt(d)
        elif d <= -lam:
            q = -k_in * sqrt(-d)
        else:
            q = k_in * d * inv_sqrt_lam
        d = p - pd
        if d >= lam:
            q -= k_out * sqrt(d)
        elif d <= -lam:
            q += k_out * sqrt(-d)
        else:
            q -= k_out * d * inv_sqrt_lam
        s = 1.0 - l * inv_l0
        g_area = ga * s * s - gb
        if g_area < 0.0:
            g_area = 0.0
        dp = q - k_area * g_area * v
        arg = (p - p_th) * inv_w_th
        p_eff = w_th * (arg + log1p(exp(-arg)) if arg > 0.0 else log1p(exp(arg)))
        force = k_force * p_eff * g_area - k_rubber * l - w - damping * v - z
        if f_lock0:
            e_lock = -l * inv_lock  # a trial stage far beyond the stop: inf, and the sub-step is rejected
            force += f_lock0 * (exp(e_lock) if e_lock < LOCK_EXPONENT_MAX else inf)
        if l <= 0.0 and v <= 0.0 and force <= 0.0:
            # Resting on the braid's full-extension stop: the stop carries the net force.
            return dp, 0.0, 0.0, 0.0
        if v > 0.0 or v < 0.0:
            # Dahl friction towards the signed sliding level (pressure, contact area, direction, rate).
            c = cos0 * s
            c = 1.0 - c * c
            contact = sqrt(c) * inv_sin0 * s if c > 0.0 else 0.0
            level = f0 + mu * p * contact if p > 0.0 else f0
            if v > 0.0:
                speed = v
                level *= up_factor
            else:
                speed = -v
                level = -level * down_factor
            if rate_gain > 0.0:
                level *= 1.0 + rate_gain * (speed * inv_v_ref) ** rate_exp
            return dp, v, force * inv_mass, speed * inv_delta * (level - z)
        return dp, v, force * inv_mass, 0.0

    def jacobian(x, p, l, v, z, ps, w, inv_mass):
        """``rhs`` and the entries of its Jacobian the scheme uses (the spool is exact)."""
        xc = 0.0 if x < 0.0 else 1.0 if x > 1.0 else x
        k_in = kq_leak + kq_open * xc ** n_char
        k_out = kq_leak + kq_open * (1.0 - xc) ** n_char
        d = ps - p
        if d >= lam:
            r = sqrt(d)
            q = k_in * r
            j_pp = -0.5 * k_in / r
        elif d <= -lam:
            r = sqrt(-d)
            q = -k_in * r
            j_pp = -0.5 * k_in / r
        else:
            q = k_in * d * inv_sqrt_lam
            j_pp = -k_in * inv_sqrt_lam
        d = p - pd
        if d >= lam:
            r = sqrt(d)
            q -= k_out * r
            j_pp -= 0.5 * k_out / r
        elif d <= -lam:
            r = sqrt(-d)
            q += k_out * r
            j_pp -= 0.5 * k_out / r
        else:
            q -= k_out * d * inv_sqrt_lam
            j_pp -= k_out * inv_sqrt_lam
        s = 1.0 - l * inv_l0
        g_area = ga * s * s - gb
        if g_area > 0.0:
            dg_area = -2.0 * ga * s * inv_l0  # d(a s^2 - b)/dl [1/mm]
        else:
            g_area = dg_area = 0.0
        dp = q - k_area * g_area * v
        arg = (p - p_th) * inv_w_th
        if arg > 0.0:
            ex = exp(-arg)
            p_eff = w_th * (arg + log1p(ex))
            slope = 1.0 / (1.0 + ex)
        else:
            ex = exp(arg)
            p_eff = w_th * log1p(ex)
            slope = ex / (1.0 + ex)
        force = k_force * p_eff * g_area - k_rubber * l - w - damping * v - z
        dforce_dl = k_force * p_eff * dg_area - k_rubber
        if f_lock0:
            e_lock = -l * inv_lock
            lock = f_lock0 * (exp(e_lock) if e_lock < LOCK_EXPONENT_MAX else inf)
            force += lock
            dforce_dl -= lock * inv_lock
        if l <= 0.0 and v <= 0.0 and force <= 0.0:
            # On the stop: only the pressure moves (the l, v, z rows of the Jacobian vanish).
            return dp, 0.0, 0.0, 0.0, j_pp, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
        if v > 0.0 or v < 0.0:
            c = cos0 * s
            c = 1.0 - c * c
            contact = sqrt(c) * inv_sin0 * s if c > 0.0 else 0.0
            if v > 0.0:
                speed, direction, dir_factor = v, 1.0, up_factor
            else:
                speed, direction, dir_factor = -v, -1.0, -down_factor
            base = f0 + mu * p * contact if p > 0.0 else f0
            dbase_dp = mu * contact if p > 0.0 else 0.0
            if rate_gain > 0.0:
                rr = (speed * inv_v_ref) ** rate_exp
                rate = 1.0 + rate_gain * rr
                drate_dspeed = rate_gain * rate_exp * rr / speed
            else:
                rate, drate_dspeed = 1.0, 0.0
            level = base * dir_factor * rate  # signed target of z
            k = speed * inv_delta
            dz = k * (level - z)
            # d(dz)/dv = sign(v) d(dz)/dspeed
            j_zv = direction * inv_delta * (level - z) + k * base * dir_factor * drate_dspeed * direction
            j_zz = -k
            j_zp = k * dbase_dp * dir_factor * rate
        else:
            dz = j_zv = j_zz = j_zp = 0.0
        return (dp, v, force * inv_mass, dz, j_pp, -k_area * g_area, -k_area * dg_area * v,
                k_force * slope * g_area * inv_mass, dforce_dl * inv_mass, -damping * inv_mass,
                -inv_mass, j_zp, j_zv, j_zz)

    def set_gate(g: float) -> None:
        nonlocal kq_open
        kq_open = kq_open_full * g

    def attempt(x, p, l, v, z, xs, ps, w, h):
        inv_mass = 1e3 / (w / GRAVITY_M_S2 + m_moving)
        (f_p, f_l, f_v, f_z, j_pp, j_pv, j_pl, j_vp, j_vl, j_vv, j_vz, j_zp, j_zv, j_zz) = \
            jacobian(x, p, l, v, z, ps, w, inv_mass)
        # W = I - g J on (p, l, v, z), J_lv = 1, solved by elimination: l, then z and p in terms of v.
        g = gamma * h
        dp_inv = 1.0 / (1.0 - g * j_pp)
        dz_inv = 1.0 / (1.0 - g * j_zz)
        g_pl = g * j_pl * dp_inv
        p1 = (g * g * j_pl + g * j_pv) * dp_inv   # k_p = P0 + p1 k_v
        zp = dz_inv * g * j_zp                    # k_z = Z0 + zp P0 + zpv k_v
        zpv = zp * p1 + dz_inv * g * j_zv
        g_vl, g_vz = g * j_vl, g * j_vz
        c_p = g * j_vp + g_vz * zp
        inv_den = 1.0 / (1.0 - g * j_vv - c_p * p1 - g * g_vl - g_vz * dz_inv * g * j_zv)
        # stage 1
        bp, bl, bv, bz = g * f_p, g * f_l, g * f_v, g * f_z
        P0 = bp * dp_inv + g_pl * bl
        Z0 = bz * dz_inv
        kv = (bv + c_p * P0 + g_vl * bl + g_vz * Z0) * inv_den
        u1p, u1l, u1v, u1z = P0 + p1 * kv, bl + g * kv, kv, Z0 + zp * P0 + zpv * kv
        # stage 2
        dx = x - xs
        y2v = v + a21 * u1v
        f_p, f_l, f_v, f_z = rhs(xs + dx * exp(-t2 * h / tau), p + a21 * u1p, l + a21 * u1l,
                                 y2v, z + a21 * u1z, ps, w, inv_mass)
        bp, bl, bv, bz = g * f_p + c21 * u1p, g * f_l + c21 * u1l, g * f_v + c21 * u1v, g * f_z + c21 * u1z
        P0 = bp * dp_inv + g_pl * bl
        Z0 = bz * dz_inv
        kv = (bv + c_p * P0 + g_vl * bl + g_vz * Z0) * inv_den
        u2p, u2l, u2v, u2z = P0 + p1 * kv, bl + g * kv, kv, Z0 + zp * P0 + zpv * kv
        # stage 3
        y3v = v + a31 * u1v + a32 * u2v
        f_p, f_l, f_v, f_z = rhs(xs + dx * exp(-t3 * h / tau), p + a31 * u1p + a32 * u2p,
                                 l + a31 * u1l + a32 * u2l, y3v,
                                 z + a31 * u1z + a32 * u2z, ps, w, inv_mass)
        bp = g * f_p + c31 * u1p + c32 * u2p
        bl = g * f_l + c31 * u1l + c32 * u2l
        bv = g * f_v + c31 * u1v + c32 * u2v
        bz = g * f_z + c31 * u1z + c32 * u2z
        P0 = bp * dp_inv + g_pl * bl
        Z0 = bz * dz_inv
        kv = (bv + c_p * P0 + g_vl * bl + g_vz * Z0) * inv_den
        u3p, u3l, u3v, u3z = P0 + p1 * kv, bl + g * kv, kv, Z0 + zp * P0 + zpv * kv
        # stage 4 (t4 = 1: the end of the sub-step; the scheme is stiffly accurate, y1 = Y4 + U4)
        x1 = xs + dx * exp(-h / tau)
        y4p = p + a41 * u1p + a42 * u2p + a43 * u3p
        y4l = l + a41 * u1l + a42 * u2l + a43 * u3l
        y4v = v + a41 * u1v + a42 * u2v + a43 * u3v
        y4z = z + a41 * u1z + a42 * u2z + a43 * u3z
        f_p, f_l, f_v, f_z = rhs(x1, y4p, y4l, y4v, y4z, ps, w, inv_mass)
        bp = g * f_p + c41 * u1p + c42 * u2p + c43 * u3p
        bl = g * f_l + c41 * u1l + c42 * u2l + c43 * u3l
        bv = g * f_v + c41 * u1v + c42 * u2v + c43 * u3v
        bz = g * f_z + c41 * u1z + c42 * u2z + c43 * u3z
        P0 = bp * dp_inv + g_pl * bl
        Z0 = bz * dz_inv
        kv = (bv + c_p * P0 + g_vl * bl + g_vz * Z0) * inv_den
        u4p, u4l, u4v, u4z = P0 + p1 * kv, bl + g * kv, kv, Z0 + zp * P0 + zpv * kv
        # Error estimate, filtered through W^-1 (damps the stiff components, Hairer & Wanner IV.8).
        bp = e1 * u1p + e2 * u2p + e3 * u3p + e4 * u4p
        bl = e1 * u1l + e2 * u2l + e3 * u3l + e4 * u4l
        bv = e1 * u1v + e2 * u2v + e3 * u3v + e4 * u4v
        bz = e1 * u1z + e2 * u2z + e3 * u3z + e4 * u4z
        P0 = bp * dp_inv + g_pl * bl
        Z0 = bz * dz_inv
        kv = (bv + c_p * P0 + g_vl * bl + g_vz * Z0) * inv_den
        err = abs(P0 + p1 * kv) * inv_tol_p
        e = abs(bl + g * kv) * inv_tol_l
        if e > err:
            err = e
        e = abs(kv) * inv_tol_v
        if e > err:
            err = e
        e = abs(Z0 + zp * P0 + zpv * kv) * inv_tol_z
        if e > err:
            err = e
        v1 = y4v + u4v
        if err < _CROSS_ERR and h > _CROSS_MIN_H and (
                v > 0.0 and v1 > 0.0 and (y2v < 0.0 or y3v < 0.0 or y4v < 0.0)
                or v < 0.0 and v1 < 0.0 and (y2v > 0.0 or y3v > 0.0 or y4v > 0.0)):
            # A stage reversed the motion although the step does not: it evaluated the friction on
            # the wrong side of its direction switch (the Dahl law's kink at v = 0), which the
            # embedded estimate cannot see (both solutions share the stages). Shorten the step.
            err = _CROSS_ERR
        return x1, y4p + u4p, y4l + u4l, v1, y4z + u4z, err

    if compiled is None:
        compiled = COMPILED
    if not compiled:
        return rhs, jacobian, attempt, set_gate, adaptive_steps(attempt, prm)
    if _ros34pw2 is None:
        raise ImportError("the compiled sub-step fmu_plant._ros34pw2 is not installed (reinstall with a C compiler)")
    scope = locals() | {"lock_exponent_max": LOCK_EXPONENT_MAX, "gravity": GRAVITY_M_S2, "cross_err": _CROSS_ERR,
                        "cross_min_h": _CROSS_MIN_H} | _loop_constants(prm)
    model = _ros34pw2.Model([scope[name] for name in _ros34pw2.NAMES])

    def set_gate_both(g: float) -> None:
        set_gate(g)  # rhs and jacobian too (Plant.derivatives)
        model.set_gate(g)

    return rhs, jacobian, model.attempt, set_gate_both, model.advance
