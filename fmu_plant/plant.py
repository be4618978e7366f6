"""The simulated tap-water muscle rig: valve, supply, muscle, hanging load, friction, sensors.

State (engineering units, as the rig's instruments show them):

=====  =======  ===============================================================
x      [-]      supply-valve spool opening (the drain valve opens ``1 - x``)
p      [MPa]    muscle gauge pressure
l      [mm]     contraction (the displacement the paper calls ``l``), >= 0
v      [mm/s]   contraction speed
z      [N]      braid-bladder friction force (Dahl state)
=====  =======  ===============================================================

Equations (docs/plant.md derives them and lists every parameter's source)::

    dx/dt = (x*(u) - x) / tau_v
    C dp/dt = Q_in - Q_out - A(l) v                 (water volume balance, hose/bladder compliance C)
    Q_in  = k_in(x)  sign(ps - p) sqrt(|ps - p|)     (supply valve, opening x)
    Q_out = k_out(x) sign(p - pd) sqrt(|p - pd|)     (drain valve, opening 1 - x)
    m dv/dt = F_muscle(p, l) - k_r l - W - c v - z  (hanging load W = m_load g)
    dz/dt = |v|/delta (sign(v) F_s(p, l, |v|) - z)  (friction, friction.py)

``A(l) = dV/dl`` is the Tondu-Lopez piston area (muscle.py) and ``F_muscle = (p - p_th)+ A(l)``.
The fully extended braid is a rigid stop at ``l = 0``.

Integration: the command is held over a communication step (zero-order hold), so the spool follows
its exact exponential solution. The other four states are stiff (the hose/bladder compliance makes the
pressure and the load a ~50 Hz hydraulic spring-mass pair, and the valve conductance near a
saturated command relaxes the pressure at ~900 1/s), so they are integrated with the linearly
implicit Rosenbrock-W method ROS34PW2 (3rd order, L-stable) over adaptive sub-steps: each sub-step
solves four 4x4 linear systems with the analytic Jacobian of the stiff couplings, its embedded
2nd-order solution estimates the local error, and the step size follows the tolerances in
``SolverParams`` (``docs/plant.md``, "Integration"). Sub-steps end exactly on every communication
point, so the trajectory does not depend on the communication step beyond those tolerances. The
effect ports (effects.py) are sampled at the start of every sub-step.

Lifecycle, as osqp's setup -> update -> solve: ``Plant(params)`` sets up, :meth:`Plant.update` changes
the load or supply pressure between steps (they may change during a run), :meth:`Plant.step` advances
time, :meth:`Plant.reset` starts over. Given the same seed, parameters and inputs, a run is
bit-for-bit reproducible.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from .effect_library import effects_from_params
from .effects import Effect
from .muscle import MuscleGeometry
from .parameters import CV_TO_SI_WATER, GRAVITY_M_S2, PlantParams
from .sensors import quantise
from .valve import flow_coefficient, orifice_flow, valve_opening

__all__ = ["Plant", "Measurement", "STATE_NAMES", "MAX_STEP_S"]

#: Names of the continuous state, in the order of :attr:`Plant.state`.
STATE_NAMES = ("x", "p_mpa", "l_mm", "v_mm_s", "z_n")

#: Longest communication step accepted by :meth:`Plant.step` [s].
MAX_STEP_S = 3600.0

#: Sensor noise is drawn from the plant's generator in blocks of this many normals.
_NOISE_BLOCK = 64


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


def _ros_transformed() -> tuple[list[list[float]], list[list[float]], list[float], list[float], list[float]]:
    """``(A, GC, M, E, c)`` of the transformed ROS34PW2 scheme (see the comment above)."""
    s, g = 4, _ROS_GAMMA
    gam = [[(_ROS_GAMMA_OFF[i][j] if j < i else g if j == i else 0.0) for j in range(s)] for i in range(s)]
    inv = [[0.0] * s for _ in range(s)]  # inverse of the lower-triangular Gamma, by forward substitution
    for col in range(s):
        for i in range(s):
            acc = (1.0 if i == col else 0.0) - sum(gam[i][k] * inv[k][col] for k in range(i))
            inv[i][col] = acc / gam[i][i]
    alpha = [[(_ROS_ALPHA[i][j] if j < i else 0.0) for j in range(s)] for i in range(s)]
    a = [[sum(alpha[i][k] * inv[k][j] for k in range(s)) for j in range(s)] for i in range(s)]
    gc = [[g * ((1.0 / g if i == j else 0.0) - inv[i][j]) for j in range(s)] for i in range(s)]
    m = [sum(_ROS_B[k] * inv[k][j] for k in range(s)) for j in range(s)]
    e = [m[j] - sum(_ROS_B_HAT[k] * inv[k][j] for k in range(s)) for j in range(s)]
    c = [sum(row) for row in alpha]
    return a, gc, m, e, c


_A, _GC, _M, _E, _C = _ros_transformed()


#: Step-size control (Hairer & Wanner's standard controller for an embedded order-2 estimate).
_SAFETY = 0.9
_GROWTH = 2.0   # largest step growth from one sub-step to the next
_SHRINK = 0.2   # largest step reduction after a rejected sub-step
_ERR_FLOOR = (_SAFETY / _GROWTH) ** 3  # errors below this allow the largest growth
_STRETCH = 1.25  # the last sub-step of a communication step may exceed the proposal by this factor
_CROSS_ERR = 2.0  # error given to a sub-step whose stages reverse the motion spuriously (shrinks it by 0.7)
_CROSS_MIN_H = 1e-4  # [s] below this a spurious stage reversal is accepted (it moves z by ~ |v| h)

#: First sub-step of a communication step: ``h = kink_scale / |change of spool target|^(1/3)``.
_KINK_SCALE_INITIAL = 0.004  # [s] after :meth:`Plant.reset` (5 ms for a first command of 5 V)
_KINK_FLOOR = 1e-3  # changes below this count as this (no change: a long first step)


def _build_model(prm: PlantParams) -> tuple[Callable[..., tuple[float, ...]], Callable[..., tuple[float, ...]],
                                             Callable[..., tuple[float, ...]], Callable[[float], None]]:
    """The right-hand side, its Jacobian and the ROS34PW2 sub-step of the rig's equations for ``prm``.

    All three are closures over plain-float constants (no attribute lookups or numpy in the hot path).

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
    sqrt, exp, log1p = math.sqrt, math.exp, math.log1p
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
            force += f_lock0 * exp(-l * inv_lock)
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
            lock = f_lock0 * exp(-l * inv_lock)
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

    return rhs, jacobian, attempt, set_gate


@dataclass(frozen=True)
class Measurement:
    """What the rig's instruments report after a step."""

    t_s: float
    """Time at the end of the step [s]."""
    l_mm: float
    """Encoder reading of the contraction [mm] (noise, 0.01 mm quantisation)."""
    p_mpa: float
    """Pressure-sensor reading [MPa(G)]."""


def _finite(name: str, value: Any) -> float:
    try:
        f = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(f):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return f


class Plant:
    """Continuous-time model of the tap-water McKibben muscle rig.

    Parameters
    ----------
    params : PlantParams, optional
        Physical parameters (defaults reproduce the paper's rig at 44 N).
    seed : int, optional
        Seed of the sensor-noise generator.
    effects : sequence of Effect, optional
        Extra physics plugged into the plant's ports (effects.py), applied in order.

    Examples
    --------
    >>> plant = Plant(seed=0)
    >>> m = plant.step(5.0, 0.1)
    >>> 0.0 <= m.l_mm < 150.0
    True
    """

    def __init__(self, params: PlantParams | None = None, *, seed: int = 0,
                 effects: Sequence[Effect] = ()) -> None:
        self.params = params if params is not None else PlantParams()
        if not isinstance(self.params, PlantParams):
            raise ValueError(f"params must be a PlantParams, got {type(self.params).__name__}")
        # the effects switched on in the parameters (effect_library.py), then the caller's own
        self.effects: tuple[Effect, ...] = tuple(effects_from_params(self.params)) + tuple(effects)
        for e in self.effects:
            if not isinstance(e, Effect):
                raise ValueError(f"effects must be Effect instances, got {type(e).__name__}")
        self._geometry = MuscleGeometry.from_params(self.params.muscle)
        vp = self.params.valve
        self._k_valve = vp.cv_max * CV_TO_SI_WATER
        self._laminar_pa = vp.laminar_dp_mpa * 1e6
        self._rhs, _, self._attempt, self._set_gate = _build_model(self.params)
        self.reset(seed=seed)

    # ------------------------------------------------------------------ lifecycle
    def reset(self, *, seed: int | None = None, load_n: float | None = None,
              supply_pressure_mpa: float | None = None) -> Measurement:
        """Start over at rest: drained muscle, fully extended, time 0.

        Parameters
        ----------
        seed : int, optional
            New noise seed (default: the previous one).
        load_n, supply_pressure_mpa : float, optional
            Initial load [N] and supply pressure [MPa] (default: from the parameters).
        """
        if seed is not None:
            if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
                raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
            self._seed = int(seed)
        self._rng = np.random.default_rng(self._seed)
        self._noise_start = None  # generator state before the current block of normals (None: no block)
        self._noise: list[float] = []
        self._noise_i = 0
        self.t_s = 0.0
        self.state = [0.0, 0.0, 0.0, 0.0, 0.0]
        self._kink_scale = _KINK_SCALE_INITIAL
        self._xs_last = 0.0
        self._gate = 1.0
        self._set_gate(1.0)
        self.u_v = self.params.valve.u_min_v
        self.load_n = self.params.load.load_n
        self.supply_pressure_mpa = self.params.supply.supply_pressure_mpa
        self.update(load_n=load_n, supply_pressure_mpa=supply_pressure_mpa)
        self._last_supply_mpa = self.supply_pressure_mpa
        for e in self.effects:
            e.reset(0.0, self.u_v, 0.0)
        self.measurement = self._measure()
        return self.measurement

    def update(self, *, load_n: float | None = None, supply_pressure_mpa: float | None = None) -> None:
        """Change the hanging load [N] or the supply pressure [MPa(G)] from now on."""
        if load_n is not None:
            load_n = _finite("load_n", load_n)
            if not 0.0 <= load_n <= 500.0:
                raise ValueError(f"load_n must be within 0..500 N, got {load_n!r}")
            self.load_n = load_n
        if supply_pressure_mpa is not None:
            supply_pressure_mpa = _finite("supply_pressure_mpa", supply_pressure_mpa)
            if not 0.0 <= supply_pressure_mpa <= 1.0:
                raise ValueError(f"supply_pressure_mpa must be within 0..1 MPa, got {supply_pressure_mpa!r}")
            self.supply_pressure_mpa = supply_pressure_mpa

    def step(self, u_v: float, dt_s: float) -> Measurement:
        """Hold the valve command ``u_v`` [V] for ``dt_s`` [s] and return the sensor readings.

        Commands outside the valve's 0..10 V range saturate in the valve amplifier.

        Raises
        ------
        ValueError
            If ``u_v`` or ``dt_s`` is not finite, or ``dt_s`` is not within (0, 3600] s. The plant
            state is unchanged then.
        FloatingPointError
            If the integration breaks down (a non-finite error estimate at the shortest sub-step;
            only with extreme parameters). The state is that of the start of the step.
        """
        u_v = _finite("u_v", u_v)
        dt_s = _finite("dt_s", dt_s)
        if not 0.0 < dt_s <= MAX_STEP_S:
            raise ValueError(f"dt_s must be within (0, {MAX_STEP_S}] s, got {dt_s!r}")
        self.u_v = u_v
        t0 = self.t_s
        t1 = t0 + dt_s
        cuts = sorted({t for e in self.effects for t in e.breakpoints(t0, t1, u_v)}) if self.effects else ()
        if cuts:  # end sub-steps exactly where an effect's port signal jumps
            saved = (list(self.state), self._xs_last, self._kink_scale, self._last_supply_mpa, self._gate)
            try:
                ta = t0
                for tb in (*cuts, t1):
                    self._advance(ta, tb - ta)
                    ta = tb
            except FloatingPointError:
                self.state, self._xs_last, self._kink_scale, self._last_supply_mpa, self._gate = saved
                self._set_gate(self._gate)
                raise
        else:
            self._advance(t0, dt_s)
        self.t_s = t1
        self.measurement = self._measure()
        return self.measurement

    # ------------------------------------------------------------------ outputs
    #: The latest sensor readings (from :meth:`reset` or :meth:`step`).
    measurement: Measurement

    @property
    def l_mm(self) -> float:
        """True contraction [mm] (no sensor noise)."""
        return self.state[2]

    @property
    def p_mpa(self) -> float:
        """True muscle gauge pressure [MPa]."""
        return self.state[1]

    def get_state(self) -> dict[str, Any]:
        """Everything needed to continue bit-identically (state, time, RNG, effects), as plain data."""
        return {
            "t_s": self.t_s, "state": list(self.state), "u_v": self.u_v, "load_n": self.load_n,
            "supply_pressure_mpa": self.supply_pressure_mpa, "seed": self._seed,
            "rng": self._rng.bit_generator.state if self._noise_start is None else self._noise_start,
            "noise_index": None if self._noise_start is None else self._noise_i,
            "effects": [e.get_state() for e in self.effects],
            "measurement": (self.measurement.t_s, self.measurement.l_mm, self.measurement.p_mpa),
            "last_supply_mpa": self._last_supply_mpa, "kink_scale_s": self._kink_scale,
            "xs_last": self._xs_last, "gate": self._gate,
        }

    def set_state(self, s: dict[str, Any]) -> None:
        """Restore what :meth:`get_state` returned.

        Raises
        ------
        ValueError
            A field that no plant could have saved (non-finite, out of its range, wrong length), named;
            a restored plant must step as the saved one did (a zero step scale would never return).
        """
        def field(name: str, lo: float = -math.inf, hi: float = math.inf, *, open_lo: bool = False) -> float:
            v = float(s[name])
            if not (math.isfinite(v) and (lo < v if open_lo else lo <= v) and v <= hi):
                raise ValueError(f"state field {name} = {v!r} must be a finite number in "
                                 f"{'(' if open_lo else '['}{lo:g}, {hi:g}]")
            return v

        field("t_s", 0.0)
        field("u_v")
        field("load_n", 0.0)
        field("supply_pressure_mpa", 0.0)
        field("last_supply_mpa", 0.0)
        if "kink_scale_s" in s:
            field("kink_scale_s", 0.0, 1.0, open_lo=True)
        if "gate" in s:
            field("gate", 0.0, 1.0)
        if len(s["state"]) != len(self.state) or not all(math.isfinite(float(v)) for v in s["state"]):
            raise ValueError(f"state field state must be {len(self.state)} finite numbers, got {s['state']!r}")
        if not all(math.isfinite(float(v)) for v in s["measurement"]) or len(s["measurement"]) != 3:
            raise ValueError(f"state field measurement must be 3 finite numbers, got {s['measurement']!r}")
        if int(s["seed"]) < 0:
            raise ValueError(f"state field seed = {s['seed']!r} must be >= 0")
        if len(s["effects"]) > len(self.effects):  # fewer is fine: a plant with an extra effect may start
            # from a state of the plant without it (the diagnosis's checkpoints); that effect keeps its own
            raise ValueError(f"state field effects has {len(s['effects'])} entries, this plant has "
                             f"{len(self.effects)} effects")
        self.t_s = float(s["t_s"])
        self.state = [float(v) for v in s["state"]]
        self.u_v = float(s["u_v"])
        self.load_n = float(s["load_n"])
        self.supply_pressure_mpa = float(s["supply_pressure_mpa"])
        self._seed = int(s["seed"])
        self._rng = np.random.default_rng()
        self._rng.bit_generator.state = s["rng"]
        self._noise_start, self._noise, self._noise_i = None, [], 0
        if s.get("noise_index") is not None:  # redraw the block the saved plant was reading from
            self._noise_start = s["rng"]
            self._noise = self._rng.standard_normal(_NOISE_BLOCK).tolist()
            self._noise_i = int(s["noise_index"])
        for e, es in zip(self.effects, s["effects"]):
            e.set_state(es)
        self.measurement = Measurement(*s["measurement"])
        self._last_supply_mpa = float(s["last_supply_mpa"])
        self._kink_scale = float(s.get("kink_scale_s", _KINK_SCALE_INITIAL))
        self._xs_last = float(s.get("xs_last", self.state[0]))
        self._gate = float(s.get("gate", 1.0))
        self._set_gate(self._gate)

    def _normal(self) -> float:
        """The generator's next standard normal, drawn in blocks (the same sequence, 20x cheaper)."""
        if self._noise_i == len(self._noise):
            self._noise_start = self._rng.bit_generator.state
            self._noise = self._rng.standard_normal(_NOISE_BLOCK).tolist()
            self._noise_i = 0
        self._noise_i += 1
        return self._noise[self._noise_i - 1]

    def _measure(self) -> Measurement:
        """Sensor readings of the current state (sensors.py: noise, then quantisation, then range)."""
        sp = self.params.sensor
        l_seen = self.state[2]
        for e in self.effects:
            l_seen = e.measurement(self.t_s, l_seen)
        if sp.encoder_noise_std_mm > 0.0:
            l_seen = l_seen + sp.encoder_noise_std_mm * self._normal()
        p_seen = self.state[1]
        if sp.pressure_noise_std_mpa > 0.0:
            p_seen = p_seen + sp.pressure_noise_std_mpa * self._normal()
        p_seen = quantise(p_seen, sp.pressure_resolution_mpa)
        return Measurement(self.t_s, quantise(l_seen, sp.encoder_resolution_mm),
                           min(max(p_seen, 0.0), sp.pressure_range_mpa))

    # ------------------------------------------------------------------ dynamics
    def _ports(self, t_s: float) -> tuple[float, float, float]:
        """Valve command [V], supply pressure [MPa], load [N] after the effects, at ``t_s``; sets the
        valve gate."""
        u, ps, w = self.u_v, self.supply_pressure_mpa, self.load_n
        for e in self.effects:
            u = e.valve_command(t_s, u)
        gate = 1.0
        for e in self.effects:
            gate *= e.valve_gate(t_s, u)
            ps = e.supply_pressure(t_s, ps)
            w = e.load(t_s, w)
        if gate != self._gate:
            self._gate = gate
            self._set_gate(gate)
        return u, ps, w

    def _valve_flows(self, x: float, p_mpa: float, ps_mpa: float) -> tuple[float, float]:
        """Flows through the supply and drain valves [m^3/s] at spool opening ``x``."""
        vp = self.params.valve
        k_in = flow_coefficient(self._k_valve, x, vp.leak_fraction, vp.characteristic_exponent, self._gate)
        k_out = flow_coefficient(self._k_valve, 1.0 - x, vp.leak_fraction, vp.characteristic_exponent, self._gate)
        return (orifice_flow(k_in, (ps_mpa - p_mpa) * 1e6, self._laminar_pa),
                orifice_flow(k_out, (p_mpa - self.params.supply.drain_pressure_mpa) * 1e6, self._laminar_pa))

    def flows_l_min(self) -> tuple[float, float]:
        """Flows through the supply and drain valves [L/min] (positive into / out of the muscle), at the
        supply pressure of the last integration sub-step (a query never calls the effect hooks, which
        may have memory)."""
        q_in, q_out = self._valve_flows(self.state[0], self.state[1], self._last_supply_mpa)
        return q_in * 6e4, q_out * 6e4

    def derivatives(self, s: Iterable[float], u_v: float, ps_mpa: float, load_n: float) -> list[float]:
        """Right-hand side ``ds/dt`` of the state equations for fixed port signals.

        Parameters
        ----------
        s : sequence of 5 floats
            State ``(x, p_mpa, l_mm, v_mm_s, z_n)``.
        u_v, ps_mpa, load_n : float
            Valve command [V], supply gauge pressure [MPa], hanging load [N].

        Returns
        -------
        list of 5 floats
            ``(dx/dt [1/s], dp/dt [MPa/s], dl/dt [mm/s], dv/dt [mm/s^2], dz/dt [N/s])``.
        """
        x, p, l, v, z = s
        vp = self.params.valve
        dx = (valve_opening(u_v, vp.u_min_v, vp.u_max_v) - x) / vp.spool_time_constant_s
        inv_mass = 1e3 / (load_n / GRAVITY_M_S2 + self.params.load.moving_mass_kg)
        return [dx, *self._rhs(x, p, l, v, z, ps_mpa, load_n, inv_mass)]

    def _advance(self, t0: float, dt: float) -> None:
        """Integrate the state over ``[t0, t0 + dt]`` with adaptive ROS34PW2 sub-steps (module docstring)."""
        sp = self.params.solver
        h_max, h_min = sp.max_substep_s, sp.min_substep_s
        vp = self.params.valve
        u_min, u_span = vp.u_min_v, vp.u_max_v - vp.u_min_v
        attempt = self._attempt
        x, p, l, v, z = self.state
        effects = self.effects
        if not effects:
            ps, w = self.supply_pressure_mpa, self.load_n
            xs = (self.u_v - u_min) / u_span
            xs = 0.0 if xs < 0.0 else 1.0 if xs > 1.0 else xs
        else:
            xs = self._xs_last
        done = 0.0
        left = dt
        h_try = 0.0  # set with the first sub-step's command below
        first = True
        sampled = False
        retry = False  # after a rejection the step must shrink (no stretching)
        while True:
            if effects and not sampled:  # the ports are sampled once per sub-step, also when it is retried
                u, ps, w = self._ports(t0 + done)
                xs = (u - u_min) / u_span
                xs = 0.0 if xs < 0.0 else 1.0 if xs > 1.0 else xs
                sampled = True
            if first and not retry:
                # The first sub-step after a command change resolves the spool's kink; its error grows
                # with the change, roughly as |change| h^3: scale the remembered proposal with it.
                kink = xs - self._xs_last
                kink = kink if kink > _KINK_FLOOR else -kink if -kink > _KINK_FLOOR else _KINK_FLOOR
                kink_root = kink ** (1.0 / 3.0)
                h_try = self._kink_scale / kink_root
            if h_try > h_max:
                h_try = h_max
            # End exactly on the communication point: stretch the step a little rather than leave a
            # short remainder, or split the rest in two.
            if left <= (h_try if retry else _STRETCH * h_try):
                h, last = left, True
            elif left < 2.0 * h_try:
                h, last = 0.5 * left, False
            else:
                h, last = h_try, False
            new = attempt(x, p, l, v, z, xs, ps, w, h)
            err = new[5]
            if err <= 1.0 or h <= h_min:
                if not err < math.inf:  # NaN or inf at the shortest step: the numbers broke down
                    raise FloatingPointError(f"plant integration failed at t = {t0 + done:.6g} s "
                                             f"(state {self.state}, parameters {self.params})")
                x, p, l, v, z = new[0], new[1], new[2], new[3], new[4]
                if l < 0.0:  # the stop is rigid: no penetration, no rebound
                    l = 0.0
                    if v < 0.0:
                        v = 0.0
                fac = _SAFETY * err ** (-1.0 / 3.0) if err > _ERR_FLOOR else _GROWTH
                if fac > _GROWTH:
                    fac = _GROWTH
                h_next = h * fac
                if first:
                    if not last or fac < 1.0 or h_next * kink_root > self._kink_scale:
                        self._kink_scale = h_next * kink_root
                    first = False
                self._last_supply_mpa = ps
                if last:
                    break
                done += h
                left = dt - done
                h_try = h_next
                sampled = retry = False
            else:
                fac = _SAFETY * err ** (-1.0 / 3.0)
                h_try = h * (fac if fac > _SHRINK else _SHRINK)
                retry = True
        self.state = [x, p, l, v, z]
        self._xs_last = xs

