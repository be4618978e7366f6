"""How a controller tells its input delay from the measurements (``input_delay_samples = -1``).

The valve may receive the command computed at sample ``k`` at once (a sequential master: the
paper's loop), one sample later (a parallel co-simulation master, which applies every output one
macro step late) or later still (a rig's transport delay). The controller scores each hypothesis
``d = 0 .. AUTO_INPUT_DELAY_SAMPLES`` by how well Eq. (1) with the prior ``theta0`` predicts the
measured ``l(k)`` under the command the valve would have had, and decides for one once it explains
the data clearly better (docs/fmu.md, "Parallel masters"; docs/control.md, "Transport delay"). This
module holds the scores (:class:`DelayScores`) and the decision rule, with its constants, each with
what it was measured on; the controller acts on the decision
(:class:`~fmu_controller.displacement_control.DisplacementController`).
"""

from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from .hysteresis_model import ASYMMETRIC, ModelState
from .ucp_mpc import held_input_run

__all__ = ["DelayScores", "AUTO_INPUT_DELAY_SAMPLES", "DELAY_FORGET", "DELAY_RATIO", "DELAY_MIN_SAMPLES", "DELAY_TIE_RATIO",
           "DELAY_CLEAR_RATIO", "DELAY_DECIDE_BY_SAMPLES", "DELAY_CHECK_SAMPLES", "DELAY_LEAD_SAMPLES",
           "DELAY_SCORES_TS_S"]


#: ``input_delay_samples = -1``: the largest delay [samples] it scores and may decide, and the
#: reference samples beyond ``Hp`` it takes (:func:`preview_lead`): 0.5 s at the paper's Ts = 0.1 s. At a
#: shorter Ts a longer delay is set (up to :data:`MAX_INPUT_DELAY_SAMPLES`): -1's decision rule below was
#: measured over these six hypotheses, and each costs a model state and a prediction a sample until it
#: decides.
AUTO_INPUT_DELAY_SAMPLES = 5

#: ``input_delay_samples = -1``: weight of the newest squared one-step error in the running means
#: (a memory of about 50 samples, 5 s at Ts = 0.1 s: over one second the two hypotheses' errors
#: overlap, the sequential/parallel ratio reaching 1.53 in a sequential loop and only 2.15 in a
#: parallel one; over five seconds at most 1.03 and at least 1.43, measured over every method,
#: 44/68 N, 0.1/0.2 Hz, two seeds) ...
DELAY_FORGET = 0.02
#: ... one hypothesis must explain the data this many times better (in mean square) to be decided,
#: between those two figures (measured with the undelayed law running; with the delayed law the
#: decision came at the minimum in every case of tests/test_displacement_control.py) ...
DELAY_RATIO = 1.25
#: ... after at least this many samples compared.
DELAY_MIN_SAMPLES = 50
#: Servo methods: a delay of 1 or more decided, and the next longer one within this factor of its mean
#: square: the rig's delay lies between the two samples (0.15 s at Ts = 0.1 s scored 1 and 2 within
#: 0.4-4 %, where a whole number of samples leaves the next one 1.09-1.96 times worse), and the longer
#: one is decided: the servo law tracked better so (mean |r - l| over 40-90 s, 0.15 s: AMPC-servo 0.36
#: against 0.68 mm, MPC-servo 0.53 against 2.3-2.5, swinging; 0.35 s: AMPC-servo 0.98 against 3.55;
#: MPC-servo's fixed predictor is poor either way there, 9.2 against 4.3-5.9). The coincidence point
#: tracked a little worse with the longer one and keeps the better scored (AMPC-UCP at 0.15 s: 2, 0.64-0.70
#: mm; 1 set, 0.63).
DELAY_TIE_RATIO = 1.05
#: A delay of 2 samples or more that the scores do not fall towards from 0 (outside
#: ``DisplacementController._valley_beyond_one``) is still decided where it explains the data this many
#: times better than both 0 and 1: a rig's 0.4-s delay under MPC-UCP at 68 N, 0.2 Hz scored 5.31, 3.67,
#: 4.77, 2.86, 1, 3.0 times the best for 0..5 (a bump at 2), where 1 tracked to 11 mm and 4 to 3.8; a
#: loop chattering with a period of a few samples, which scores that period like 0, reached 1.68
#: (h = Ts/4 in a parallel master) and 1.31 (a fixed predictor on an off-nominal rig).
DELAY_CLEAR_RATIO = 2.0
#: ``input_delay_samples = -1``: if neither hypothesis has won by :data:`DELAY_RATIO` after this many
#: samples (a delay of a fraction of a sample: a rig's transport delay), the one that predicts better
#: is taken.
DELAY_DECIDE_BY_SAMPLES = 300
#: ``input_delay_samples`` set: the first this many samples are scored as -1 scores them (the delays
#: 0 .. max(:data:`AUTO_INPUT_DELAY_SAMPLES`, the delay set)), to tell a set delay the measurements
#: contradict (:attr:`DisplacementController.delay_evidence`): as long as -1 may take to decide,
#: since the start-up mode hides a wrong delay for its first seconds (100 samples do not tell
#: AMPC-servo's 0 in a parallel master); the scores cost about 20 us a sample (the direct loop of
#: benchmarks/fmu_cosim.py: 77 and 93 us a sample over 40 s without and with).
DELAY_CHECK_SAMPLES = DELAY_DECIDE_BY_SAMPLES

#: ``input_delay_samples = -1``, undecided: the delayed law uses the corrected one-step prediction
#: (:class:`~fmu_controller.delay_predictor.DelayPredictor`) once this many samples are compared and
#: the parallel hypothesis leads.
DELAY_LEAD_SAMPLES = 20
#: The sampling period [s] at which the delay scores' memory and sample counts above were measured:
#: at another ``Ts`` they span the same seconds (:meth:`DisplacementController.delay_check_samples`).
DELAY_SCORES_TS_S = 0.1


class DelayScores:
    """The running mean squared one-step errors of Eq. (1) with the prior ``theta0`` under each input
    delay ``d = 0 .. largest`` [samples]: under ``d`` the valve had the output ``y(k-1-d)`` over
    ``[t_k-1, t_k)`` (0: a sequential master, 1: a parallel one, more: a rig's transport delay as well).
    Each hypothesis keeps its own model state. The prior, not an adaptive estimate: in the first
    seconds the estimate can be far off.

    The weight of the newest error and the sample counts of the rule span the seconds they were
    measured over at :data:`DELAY_SCORES_TS_S`, at any ``Ts`` (counted in samples, at Ts = 0.02 s the
    300 samples of :data:`DELAY_CHECK_SAMPLES` were 6 s, inside the start-up mode, where a set delay
    that was right was scored wrong).

    Parameters
    ----------
    theta0 : ndarray
        Eq. (1)'s parameters the hypotheses predict with (15, :data:`~fmu_controller.hysteresis_model.ASYMMETRIC`).
    largest : int
        The longest delay scored [samples].
    ts_s : float
        Sampling period [s].
    """

    def __init__(self, theta0: np.ndarray, largest: int, ts_s: float) -> None:
        self.largest = int(largest)
        self._theta0 = theta0
        self._lin0 = theta0[:3].tolist()
        scale = ts_s / DELAY_SCORES_TS_S
        self._forget = DELAY_FORGET * scale if scale < 1.0 / DELAY_FORGET else 1.0
        #: Samples scored before any decision, by which the better is taken, that a set delay is checked
        #: over, and after which the parallel hypothesis's lead counts (:data:`DELAY_MIN_SAMPLES` ...).
        self.min_n, self.decide_n, self.check_n, self.lead_n = (
            max(1, round(n / scale)) for n in (DELAY_MIN_SAMPLES, DELAY_DECIDE_BY_SAMPLES, DELAY_CHECK_SAMPLES,
                                               DELAY_LEAD_SAMPLES))
        self.reset(0.0)

    def reset(self, l0_mm: float) -> None:
        """Start over with no sample scored, every hypothesis's model at rest at ``l0_mm`` [mm]."""
        n = self.largest + 1
        #: Mean squared one-step error [mm^2] under each delay 0 .. largest.
        self.ms = [0.0] * n
        #: Samples scored so far.
        self.compared = 0
        self._models = [ModelState(ASYMMETRIC, l_init=(l0_mm, l0_mm, l0_mm), u_init=0.0) for _ in range(n)]

    def start(self, l_mm: float) -> None:
        """The first measurement ``l(0)`` [mm]: every hypothesis's model observes it."""
        lin0 = self._lin0
        for model in self._models:
            model.observe_unchecked(l_mm, lin0[0], lin0[1], lin0[2])

    def score(self, l_mm: float, outputs: Sequence[tuple[float, float]]) -> None:
        """Score the measured ``l(k)`` [mm]: each hypothesis ``d`` predicts it under the valve command
        ``outputs[d][0]`` [V] (``outputs``: the controller's outputs ``(u, u_c)``, newest first,
        ``y(k-1), y(k-2), ...``), then observes it."""
        th0, lin0, ms, forget = self._theta0, self._lin0, self.ms, self._forget
        for d, model in enumerate(self._models):
            u = outputs[d][0]
            model.apply(u)
            e = l_mm - held_input_run(model, th0, lin0, u, 1)[0]
            model.observe_unchecked(l_mm, lin0[0], lin0[1], lin0[2])
            ms[d] += forget * (e * e - ms[d])
        self.compared += 1

    def verdict(self, servo_mechanism: bool) -> int | None:
        """``input_delay_samples = -1``, the delayed law (``d = 1``) running: the delay [samples] the
        scores decide for, or None while they do not.

        Once the best delay of 2 or more that the scores fall towards from 1 (:meth:`valley_beyond_one`,
        or any that explains the data :data:`DELAY_CLEAR_RATIO` times better than both 0 and 1) is
        :data:`DELAY_RATIO` times better than both 0 and 1, that one; else once the parallel hypothesis
        is that much better than the sequential one, 1 (or a longer delay that scores better still); once
        the sequential one is, 0; after :data:`DELAY_DECIDE_BY_SAMPLES` samples the best. With
        ``servo_mechanism`` the longer of two neighbouring delays that score within
        :data:`DELAY_TIE_RATIO` is taken (:meth:`longer_if_tied`). Nothing before
        :data:`DELAY_MIN_SAMPLES`.
        """
        ms = self.ms
        if self.compared < self.min_n:
            return None
        ms_seq, ms_par = ms[0], ms[1]
        late = self.compared >= self.decide_n
        clear = [d for d in range(2, len(ms)) if DELAY_CLEAR_RATIO * ms[d] < min(ms_seq, ms_par)]
        far = min((*self.valley_beyond_one(), *clear), key=ms.__getitem__, default=None)
        if far is not None and (DELAY_RATIO * ms[far] < min(ms_seq, ms_par) or (late and ms[far] < min(ms_seq, ms_par))):
            return self.longer_if_tied(far, servo_mechanism)  # a rig's transport delay: each command far samples on
        if DELAY_RATIO * ms_par < ms_seq or (late and ms_par <= ms_seq):
            # a parallel master (or a rig's delay of about a sample), unless a longer delay scores better
            # still (a rig's delay between 1 and 2 samples)
            return self.longer_if_tied(far if far is not None and ms[far] < ms_par else 1, servo_mechanism)
        if DELAY_RATIO * ms_seq < ms_par or late:
            return 0  # a sequential master: the valve had the last output over [t_k-1, t_k)
        return None

    def valley_beyond_one(self) -> range:
        """The delays of 2 samples or more that a rig's transport delay can be on the scores: those reached
        from 0, through 1, while each next one scores no worse than :data:`DELAY_TIE_RATIO` times the one
        before. A transport delay's scores fall towards it from the shorter delays. A loop that chatters
        with a period of a few samples (the delayed law on a rig whose command acts within a fraction of a
        sample: a parallel master sub-stepping at Ts/4; the delayed law of a fixed predictor on a rig whose
        constants are off) repeats its command every period, so the delay of one period scores as well as
        0 whatever lies between (0.025 s at 68 N, 0.2 Hz: 1.68, 3.68, 6.98, 1 times the best for 0 .. 3
        samples; deciding 3 tracks MPC-servo to 2.0 mm, 0 to 0.42; MPC-UCP on an off-nominal rig without a
        delay: 1.31, 1.86, 1.0, deciding 2 tracked to 1.60 mm, 0 to 1.18)."""
        ms, d = self.ms, 0
        while d + 1 < len(ms) and ms[d + 1] <= DELAY_TIE_RATIO * ms[d]:
            d += 1
        return range(2, d + 1)

    def longer_if_tied(self, d: int, servo_mechanism: bool) -> int:
        """``d``, or with ``servo_mechanism`` ``d + 1`` where that one scores within :data:`DELAY_TIE_RATIO`
        of it (a delay between the two samples: the servo law compensates the longer one)."""
        ms = self.ms
        longer = servo_mechanism and d + 1 < len(ms) and ms[d + 1] <= DELAY_TIE_RATIO * ms[d]
        return d + 1 if longer else d

    def parallel_leads(self) -> bool:
        """Whether :data:`DELAY_LEAD_SAMPLES` samples are scored and the parallel hypothesis (1) predicts
        better than the sequential one (0)."""
        return self.compared >= self.lead_n and self.ms[1] < self.ms[0]

    @property
    def checked(self) -> bool:
        """Whether the :data:`DELAY_CHECK_SAMPLES` samples a set delay is checked over are scored."""
        return self.compared >= self.check_n

    def evidence(self, lag: int) -> tuple[int, float] | None:
        """``(d, ratio)`` where another delay ``d`` explains the samples scored :data:`DELAY_RATIO` times
        better than ``lag`` or more (``ratio``: ``lag``'s mean squared error over ``d``'s), else None."""
        ms = self.ms
        best = min(range(len(ms)), key=ms.__getitem__)
        if best != lag and DELAY_RATIO * ms[best] < ms[lag]:
            return best, ms[lag] / ms[best] if ms[best] > 0.0 else math.inf
        return None

    def get_state(self) -> dict[str, Any]:
        """The scores as plain data: ``delay_scores``, ``compared``, ``delay_models``."""
        return {"delay_scores": list(self.ms), "compared": self.compared,
                "delay_models": [model.get_state() for model in self._models]}

    def set_state(self, scores: Sequence[float], compared: int, models: Sequence[Any] | None) -> None:
        """Restore what :meth:`get_state` returned (``models`` None: the models as they are).

        Raises
        ------
        ValueError
            ``scores`` not ``largest + 1`` finite numbers >= 0, ``compared`` < 0, or ``models`` of
            another length.
        """
        n = self.largest + 1
        values = [float(x) for x in scores]
        if len(values) != n or not all(map(math.isfinite, values)) or min(values, default=0.0) < 0 or int(compared) < 0:
            raise ValueError(f"state fields delay_scores ({n} finite numbers >= 0) and compared (>= 0) do not fit, got "
                             f"{list(scores)!r}, {compared!r}")
        if models is not None and len(models) != n:
            raise ValueError(f"state field delay_models must hold {n} model states, got {len(models)}")
        if models is not None:
            for model, saved in zip(self._models, models):
                model.set_state(saved)
        self.ms, self.compared = values, int(compared)
