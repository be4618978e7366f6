"""CPU-independent arithmetic of the diagnosis (tapmuscle/diagnosis/reproducible.py): correctly rounded
sums, running window sums, grid snapping, and a diagnosis that is the same bit for bit under another
BLAS kernel and another numpy SIMD level."""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
from fractions import Fraction

import numpy as np
import pytest

from tapmuscle.diagnosis.reproducible import (GRID_BITS, broyden_update, dot, moving_sum, norm, snap, snap_relative,
                                              sse)


def _vectors(seed: int, n: int) -> np.ndarray:
    """Values over twelve decades, both signs: where the order of summation changes the last bits."""
    rng = np.random.default_rng(seed)
    return rng.standard_normal(n) * 10.0 ** rng.uniform(-6, 6, n)


@pytest.mark.parametrize("seed", range(5))
def test_sse_and_dot_are_the_exact_sums_correctly_rounded(seed):
    a, b = _vectors(seed, 257), _vectors(seed + 100, 257)
    # the exact sum of the rounded products, then one rounding: what no summation order can beat
    assert sse(a) == float(sum(Fraction(float(v * v)) for v in a))
    assert dot(a, b) == float(sum(Fraction(float(u * v)) for u, v in zip(a, b)))
    assert norm(a) == pytest.approx(float(np.linalg.norm(a)), rel=1e-14)


@pytest.mark.parametrize("seed", range(5))
def test_sse_and_dot_do_not_depend_on_the_order_of_summation(seed):
    """The property a BLAS kernel's dot lacks: a permutation of the terms gives the same bits."""
    a, b = _vectors(seed, 1801), _vectors(seed + 100, 1801)
    perm = np.random.default_rng(seed).permutation(a.size)
    assert sse(a[perm]) == sse(a) and dot(a[perm], b[perm]) == dot(a, b)
    assert sse(a[::-1]) == sse(a)


def test_dot_refuses_vectors_of_different_lengths():
    with pytest.raises(ValueError, match="lengths 3 and 4"):
        dot(np.ones(3), np.ones(4))


@pytest.mark.parametrize("seed", range(5))
def test_broyden_update_meets_the_secant_condition_and_keeps_the_orthogonal_directions(seed):
    rng = np.random.default_rng(seed)
    J, dx, df = rng.normal(size=(40, 6)), rng.normal(size=6), rng.normal(size=40)
    J1 = broyden_update(J, dx, df)
    # the secant condition J+ dx = df, to the rounding of a 6-term sum of O(1) terms
    assert np.allclose(J1 @ dx, df, rtol=0, atol=1e-12 * (1 + np.abs(df).max()))
    # a direction orthogonal to the step sees the old Jacobian
    v = rng.normal(size=6)
    v -= dx * (v @ dx) / (dx @ dx)
    assert np.allclose(J1 @ v, J @ v, rtol=0, atol=1e-12)
    assert broyden_update(J, np.zeros(6), df) is J


@pytest.mark.parametrize("n, k", [(1, 1), (5, 2), (5, 5), (100, 1), (100, 7), (100, 10), (1801, 50)])
def test_moving_sum_is_numpys_valid_and_same_convolution(n, k):
    x = np.random.default_rng(n + k).random(n)
    assert np.allclose(moving_sum(x, k), np.convolve(x, np.ones(k), mode="valid"), rtol=1e-12, atol=1e-12)
    assert np.allclose(moving_sum(x, k, centred=True), np.convolve(x, np.ones(k), mode="same"),
                       rtol=1e-12, atol=1e-12)


def test_moving_sum_refuses_a_window_longer_than_the_values():
    with pytest.raises(ValueError, match="k=6 for 5 values"):
        moving_sum(np.ones(5), 6)
    with pytest.raises(ValueError, match="k=0"):
        moving_sum(np.ones(5), 0, centred=True)


def test_snap_puts_points_on_the_grid_and_absorbs_last_bit_differences():
    x = _vectors(7, 1000) * 1e-6  # scaled coordinates: a few prior sds at most
    s = snap(x)
    q = 2.0 ** -GRID_BITS
    assert np.all(np.abs(s - x) <= q / 2)
    assert np.array_equal(snap(s), s)
    assert np.array_equal(np.round(s / q), s / q)  # exact multiples of the grid
    # one ulp either way (what another BLAS kernel gives) lands on the same grid point
    assert np.array_equal(snap(np.nextafter(x, np.inf)), s) and np.array_equal(snap(np.nextafter(x, -np.inf)), s)


@pytest.mark.parametrize("v", [1.0, -3.7e-5, 123456.789, 2.0 ** -40, 0.0, float("inf"), float("nan")])
def test_snap_relative_rounds_to_grid_bits_significant_bits(v):
    s = snap_relative(v)
    if v == 0.0 or not np.isfinite(v):
        assert s == v or (np.isnan(s) and np.isnan(v))
        return
    assert abs(s - v) <= abs(v) * 2.0 ** -GRID_BITS
    assert snap_relative(s) == s
    assert snap_relative(float(np.nextafter(v, np.inf))) == s


# The same diagnosis in two processes that differ only in the BLAS kernel and numpy's SIMD level. Before
# the diagnosis summed and snapped with this module, these gave different constants (and on the field
# demo's borderline recordings, different verdicts).
_CHILD = """
import json, hashlib, sys
import numpy as np
from tapmuscle.diagnosis.candidates import candidate
from tapmuscle.diagnosis.demo import DEMO_MODEL, record
from tapmuscle.diagnosis.diagnose import diagnose
off = {"muscle.rubber_stiffness_n_per_mm": 1.38, "friction.base_n": 6.4, "valve.cv_max": 1.35}
cols = record(DEMO_MODEL.with_values(**off, **{"delay.delay_s": 0.3}), "steps", 3, duration_s=150.0)
d = diagnose(cols["t_s"], cols["u_v"], cols["l_mm"], DEMO_MODEL,
             candidates=[candidate(n) for n in ("transport_delay", "sensor_drift", "backlash", "input_map")])
print(json.dumps({"named": d.named, "verdict": d.verdict, "simulations": d.simulations,
                  "after": hashlib.sha256(np.ascontiguousarray(d.y_after_mm).tobytes()).hexdigest(),
                  "constants": {k: v.hex() for k, v in sorted(d.calibration.params.dotted().items())
                                if isinstance(v, float)},
                  "tried": [c.get("parameters") for c in d.candidates]}))
"""


def _other_floating_point_path(env: dict[str, str]) -> dict[str, str]:
    """``env`` with OpenBLAS's most basic x86-64 kernel (Prescott, SSE3) on one thread, and numpy
    without the kernels it dispatches to for this CPU (as ``.ci/run``'s second pass)."""
    from tapmuscle.provenance import cpu_features  # noqa: PLC0415

    other = dict(env, OPENBLAS_CORETYPE="Prescott", OPENBLAS_NUM_THREADS="1")
    features = cpu_features()
    if features not in ("baseline", "unknown"):
        other["NPY_DISABLE_CPU_FEATURES"] = features
    return other


@pytest.mark.slow
@pytest.mark.skipif(platform.machine().lower() not in ("x86_64", "amd64"), reason="OpenBLAS kernel names are x86-64's")
def test_the_diagnosis_is_the_same_under_another_blas_kernel_and_simd_level():
    """Constants off, a 0.3 s delay: the calibration's least squares, the input map's and every
    decision after them give the same bits with OpenBLAS's Prescott kernel and numpy's baseline loops
    as with what this CPU chooses (the two processes run side by side)."""
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_CORETYPE", "NPY_DISABLE_CPU_FEATURES")}
    procs = [subprocess.Popen([sys.executable, "-c", _CHILD], env=e, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True) for e in (env, _other_floating_point_path(env))]
    outs = [p.communicate(timeout=900) for p in procs]
    for p, (_, err) in zip(procs, outs):
        assert p.returncode == 0, err[-3000:]
    a, b = (json.loads(out.strip().splitlines()[-1]) for out, _ in outs)
    assert a["named"] == ["transport_delay"]
    assert a == b
