"""One joint's relative orientation from two live sensors, sample by sample, no magnetometer.

:class:`JointStream` runs the joint filter of :mod:`margtrack.joint.kernel` (the online
estimate of ``margtrack joint`` and ``margtrack body --no-mag``) on a stream of batches of
both sensors' rates and specific forces, carrying its state from batch to batch:

- the joint-centre specific forces need the rate's derivative, a central difference that
  reaches two samples ahead (:func:`~margtrack.joint.kernel.rate_derivative`): the filter
  runs two samples behind the newest, and the last two samples of a batch are predicted
  from the filter's state by both gyroscopes (no correction) until the next batch brings
  the samples that let the filter correct them;
- the lever arms (joint centre to each sensor, m): given, or *estimated once* by the same
  least squares as ``margtrack body`` (:func:`~margtrack.joint.lever_arms.estimate_lever_arms`)
  after :data:`FIT_MOTION_S` of motion (either sensor turning faster than
  :data:`~margtrack.body.chain.MOVING_RAD_S`) within the last :data:`BUFFER_S`, and then
  frozen; until then the filter runs with zero lever arms, and at the fit it is run again
  over the buffered samples with the lever arms found, so what follows is what the online
  estimate with those lever arms from the buffer's start would give. A fit that fails
  (too little rotation) is tried again after every further second of motion;
- the input policy: a sample that is held (the sensor missing from its frame), stale, not
  finite, at or beyond the sensors' ranges, or a zero specific force is *bad*: a bad rate is
  replaced by the sensor's last good one (zero while stale: the orientation held); the
  accelerometers are used only where nothing is bad within two samples (the derivative's
  reach), as in :func:`margtrack.joint.pair.pair_inputs`; a restart of either sensor (clock
  resync, stale sensor back) or an interval beyond ``max_gap_s`` is not integrated over
  (the filter levels both sensors again, the relative heading uncertain again).

The relative heading is observable only while the joint centre accelerates horizontally:
:attr:`JointStream.settled` says the lever arms are in force and the joint has moved for
:data:`~margtrack.body.chain.SETTLE_S` since (or the fit's buffer held that much motion).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from margtrack.body.chain import MOVING_RAD_S, SETTLE_S
from margtrack.joint.lever_arms import LeverArms, estimate_lever_arms
from margtrack.joint.params import JointParams

Array = NDArray[np.float64]

__all__ = ["BUFFER_S", "FIT_MOTION_S", "JointStream"]

#: motion (s of either sensor turning faster than MOVING_RAD_S) before the lever arms are
#: estimated: about three strides of a walk, the fit's samples many times its 6 unknowns
FIT_MOTION_S = 3.0
#: longest stretch of samples kept for the lever-arm fit and the run after it, s
BUFFER_S = 20.0
_LOOKAHEAD = 2  # samples the rate derivative reaches ahead (and back)
_G = 9.80665


class JointStream:
    """The relative orientation ``conj(q_parent) ⊗ q_child`` of one joint, batch by batch.

    Parameters
    ----------
    rate_hz : nominal sample rate, Hz (sizes the fit buffer; 100 Hz when unknown).
    lever_arms : given lever arms (:class:`~margtrack.joint.lever_arms.LeverArms`), or None
        to estimate them once (module docstring).
    params : the joint filter's :class:`~margtrack.joint.params.JointParams`.
    fit_motion_s, buffer_s : module constants :data:`FIT_MOTION_S`, :data:`BUFFER_S`.
    """

    def __init__(self, rate_hz: float | None, lever_arms: LeverArms | None = None,
                 params: JointParams | None = None, fit_motion_s: float = FIT_MOTION_S,
                 buffer_s: float = BUFFER_S) -> None:
        from margtrack.joint.relative import _coefficients

        self.params = params if params is not None else JointParams()
        self._coeffs = _coefficients(self.params)
        self.lever_arms = lever_arms
        self.fit_error = ""
        #: filtered samples without a usable measurement (bad within two samples)
        self.unmeasured = 0
        self.fit_motion_s = float(fit_motion_s)
        self._buffer_n = max(round(buffer_s * (rate_hz or 100.0)), 100)
        self._r = lever_arms.r_m if lever_arms is not None else np.zeros((2, 3))
        self._gyr_range = np.radians(self.params.gyr_range_deg_s)
        self._acc_range = self.params.acc_range_g * _G
        self._q = np.tile([1.0, 0.0, 0.0, 0.0], (2, 1))
        self._p = np.zeros((5, 5))
        self._started = False
        self._last_good = np.zeros((2, 3))
        # the last samples: up to two filtered ones (the derivative's context) and the
        # ``_pending`` newest not filtered yet
        self._t = np.zeros(0)
        self._gyr = np.zeros((2, 0, 3))
        self._acc = np.zeros((2, 0, 3))
        self._bad = np.zeros(0, dtype=bool)
        self._restart = np.zeros(0, dtype=bool)
        self._pending = 0
        # filtered samples kept for the lever-arm fit (list of arrays, joined at the fit)
        self._kept: list[tuple[Array, Array, Array, NDArray[np.bool_], NDArray[np.bool_]]] = []
        self._kept_n = 0
        self._kept_t = np.nan  # time of the last filtered sample, s
        self._motion_s = 0.0
        self._next_try_s = self.fit_motion_s

    # -- state seen from outside ----------------------------------------------------------
    @property
    def settled(self) -> bool:
        """Lever arms in force and the relative heading found (module docstring)."""
        if self.lever_arms is None:
            return False
        if self.lever_arms.source == "estimated":
            return True  # the fit's buffer held FIT_MOTION_S of motion
        return self._motion_s >= SETTLE_S

    @property
    def motion_s(self) -> float:
        """Seconds of motion seen so far (either sensor faster than MOVING_RAD_S), s."""
        return self._motion_s

    # -- one batch ------------------------------------------------------------------------
    def step(self, t_s: Array, gyr: Array, acc: Array, held: NDArray[np.bool_],
             restart: NDArray[np.bool_]) -> tuple[Array, NDArray[np.bool_]]:
        """The relative orientation at each of the batch's N samples.

        t_s (N,) s, increasing; gyr, acc (2, N, 3) rad/s and m/s², parent's then child's,
        sensor frames; held (N,) bool: either sample held or stale (not measured);
        restart (N,) bool: either sensor restarts there.

        Returns ``rel`` (N, 4) ``conj(q_parent) ⊗ q_child`` (identity before the filter's
        first usable sample) and ``predicted`` (N,) bool: the sample's output is the
        gyroscopes' prediction (the newest two, or no usable measurement within two samples).
        """
        from margtrack.joint.kernel import centre_forces, filter_pass

        n = t_s.shape[0]
        gyr, acc, bad = self._screen(gyr, acc, held)
        restart = restart.copy()
        if self._t.size:
            restart[0] |= t_s[0] - self._t[-1] > self.params.max_gap_s
        restart[1:] |= np.diff(t_s) > self.params.max_gap_s
        t = np.concatenate([self._t, t_s])
        g = np.concatenate([self._gyr, gyr], axis=1)
        a = np.concatenate([self._acc, acc], axis=1)
        b = np.concatenate([self._bad, bad])
        r = np.concatenate([self._restart, restart])
        w = t.shape[0]
        h = w - n  # where the batch starts in the window
        lo = h - self._pending  # first sample to filter
        hi = max(w - _LOOKAHEAD, lo)  # filter up to (excluding) hi
        meas_ok = np.convolve(b, np.ones(2 * _LOOKAHEAD + 1), mode="same") == 0
        c = centre_forces(t, g, a, self._r)
        rel = np.empty((n, 4))
        predicted = np.ones(n, dtype=bool)
        if hi > lo:
            s = max(lo - 1, 0)  # one filtered sample before: its rate starts the interval
            ok = meas_ok[s:hi].copy()
            rs = r[s:hi].copy()
            if s < lo:
                ok[0] = False
                rs[0] = False
            q, rel_f, p, first = filter_pass(t[s:hi], np.ascontiguousarray(g[:, s:hi]),
                                             np.ascontiguousarray(c[:, s:hi]), ok, rs,
                                             self._q, self._p, self._started, self._coeffs)
            self._started = self._started or first < hi - s
            self._after_filtering(q, p, rs, ok)
            self.unmeasured += int(np.count_nonzero(~meas_ok[lo:hi]))
            out = np.arange(max(lo, h), hi)  # the batch's samples filtered now
            rel[out - h] = rel_f[out - s]
            predicted[out - h] = ~meas_ok[out]
            self._keep(t[lo:hi], g[:, lo:hi], a[:, lo:hi], meas_ok[lo:hi], r[lo:hi])
        tail = np.arange(max(hi, h), w)  # the batch's newest: predicted by the gyroscopes
        if tail.size:
            s = hi - 1 if hi >= 1 else 0
            ok = np.zeros(w - s, dtype=bool)
            _, rel_p, _, _ = filter_pass(t[s:], np.ascontiguousarray(g[:, s:]),
                                         np.ascontiguousarray(c[:, s:]), ok, r[s:].copy(),
                                         self._q, self._p, True, self._coeffs)
            rel[tail - h] = rel_p[tail - s] if self._started else [1.0, 0.0, 0.0, 0.0]
        keep = max(hi - _LOOKAHEAD, 0)
        self._t, self._gyr, self._acc = t[keep:], g[:, keep:], a[:, keep:]
        self._bad, self._restart = b[keep:], r[keep:]
        self._pending = w - hi
        self._maybe_fit()
        return rel, predicted

    def _screen(self, gyr: Array, acc: Array, held: NDArray[np.bool_]
                ) -> tuple[Array, Array, NDArray[np.bool_]]:
        """Bad samples found, bad rates replaced by the last good ones (module docstring)."""
        gyr = np.array(gyr, dtype=np.float64)
        acc = np.array(acc, dtype=np.float64)
        g_bad = ~np.isfinite(gyr).all(axis=2) | (np.abs(gyr) >= self._gyr_range).any(axis=2)
        a2 = np.einsum("snk,snk->sn", acc, acc)
        a_bad = ~np.isfinite(a2) | (a2 >= self._acc_range**2) | (a2 == 0.0)
        bad = held | g_bad.any(axis=0) | a_bad.any(axis=0)
        if g_bad.any():
            for s in range(2):
                for k in np.flatnonzero(g_bad[s]):
                    gyr[s, k] = self._last_good[s] if k == 0 else gyr[s, k - 1]
        if gyr.shape[1]:
            self._last_good = gyr[:, -1].copy()
        if a_bad.any():
            acc[~np.isfinite(acc)] = 0.0
        return gyr, acc, bad

    def _after_filtering(self, q: Array, p: Array, restart: NDArray[np.bool_],
                         ok: NDArray[np.bool_]) -> None:
        """Keep the filter's state; a restart with no usable sample after it levels again."""
        self._q = np.ascontiguousarray(q[:, -1])
        self._p = p
        hits = np.flatnonzero(restart)
        if hits.size and not ok[hits[-1]:].any():
            self._started = False  # level both from the next usable sample, headings kept

    # -- the lever-arm fit ----------------------------------------------------------------
    def _keep(self, t: Array, g: Array, a: Array, ok: NDArray[np.bool_],
              r: NDArray[np.bool_]) -> None:
        """Count the motion of the filtered samples and keep the last ``buffer_s`` of them
        (the lever-arm fit, :meth:`smoothed`)."""
        if t.size == 0:
            return
        moving = (np.einsum("snk,snk->sn", g, g) > MOVING_RAD_S**2).any(axis=0) & ok
        if moving.any():
            dt = np.diff(t, prepend=self._kept_t if np.isfinite(self._kept_t) else t[0])
            self._motion_s += float(np.minimum(dt, self.params.max_gap_s)[moving].sum())
        self._kept_t = float(t[-1])
        # slices of this step's own window arrays (new every step): kept without copies
        self._kept.append((t, g, a, ok, r))
        self._kept_n += t.size
        while self._kept_n - self._kept[0][0].size >= self._buffer_n:
            self._kept_n -= self._kept.pop(0)[0].size

    def _history(self) -> tuple[Array, Array, Array, NDArray[np.bool_], NDArray[np.bool_]]:
        parts = self._kept
        return (np.concatenate([k[0] for k in parts]),
                np.concatenate([k[1] for k in parts], axis=1),
                np.concatenate([k[2] for k in parts], axis=1),
                np.concatenate([k[3] for k in parts]),
                np.concatenate([k[4] for k in parts]))

    def smoothed(self, t_s: Array) -> Array:
        """The relative orientation (M, 4) at the kept samples nearest ``t_s`` (M,) s, from
        the filter run *backwards* from its present state over the kept samples (as the
        offline estimate's backward pass, :func:`margtrack.joint.relative.relative_orientation`):
        each output uses every kept sample after it, so a still stretch before the joint
        moved gets the relative heading the motion revealed. Identity with nothing kept.
        """
        from margtrack.joint.kernel import centre_forces, filter_pass

        out = np.tile([1.0, 0.0, 0.0, 0.0], (t_s.shape[0], 1))
        if not self._kept or not self._started:
            return out
        t, g, a, ok, r = self._history()
        c = centre_forces(t, g, a, self._r)
        back_restart = np.zeros_like(r)
        back_restart[1:] = r[::-1][:-1]
        _, rel, _, _ = filter_pass(-t[::-1], np.ascontiguousarray(-g[:, ::-1]),
                                   np.ascontiguousarray(c[:, ::-1]), ok[::-1].copy(),
                                   back_restart, self._q, self._p, True, self._coeffs)
        rel = rel[::-1]
        idx = np.clip(np.searchsorted(t, t_s), 0, t.size - 1)
        prev = np.maximum(idx - 1, 0)
        idx = np.where(np.abs(t[prev] - t_s) < np.abs(t[idx] - t_s), prev, idx)
        return rel[idx]

    def _maybe_fit(self) -> None:
        if self.lever_arms is not None or self._motion_s < self._next_try_s:
            return
        from margtrack.joint.kernel import centre_forces, filter_pass

        t, g, a, ok, r = self._history()
        try:
            arms = estimate_lever_arms(t, g, a, ok)
        except ValueError as exc:
            self.fit_error = str(exc)
            self._next_try_s = self._motion_s + 1.0
            return
        self.lever_arms, self._r, self.fit_error = arms, arms.r_m, ""
        r[0] = False
        c = centre_forces(t, g, a, self._r)
        q, _, p, first = filter_pass(t, g, c, ok, r, np.tile([1.0, 0.0, 0.0, 0.0], (2, 1)),
                                     np.zeros((5, 5)), False, self._coeffs)
        self._started = first < t.size
        self._after_filtering(q, p, r, ok)
