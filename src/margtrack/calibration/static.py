"""Still periods of a recording, found from the data (so nobody has to mark them by hand).

A sample ``i`` is *still* when the trailing window of the last ``window_s`` seconds ending at
``i`` is quiet: the norm of the window's mean angular rate is at most ``max_rate_rad_s``
(rejects slow steady turns, whose rate varies little) and the square root of the summed
per-axis variances of the angular rate and of the specific force are at most
``gyr_std_rad_s`` and ``acc_std_m_s2``. The window is causal, so the same test runs live
(:class:`StillnessDetector`, one sample at a time) and on a whole recording
(:func:`still_mask`, :func:`static_segments`). A still *segment* is reported from the start
of the first quiet window to its last sample, so it covers the whole quiet period.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from margtrack.recording import Recording

Array = NDArray[np.float64]

__all__ = [
    "StillnessDetector",
    "StillnessSettings",
    "segment_means",
    "static_segments",
    "still_mask",
]


@dataclass(frozen=True)
class StillnessSettings:
    """Thresholds of the stillness test (module docstring).

    window_s : length of the trailing window, s, > 0 (default 0.5 s: long enough to average
        MEMS noise, short enough to find one-second holds). Raising it makes the test
        stricter about brief twitches and the segments start later.
    max_rate_rad_s : largest norm of the window's mean rate, rad/s, > 0 (default 0.1 rad/s
        = 5.7 deg/s: above the null of consumer gyroscopes, which is under ~3 deg/s,
        below any deliberate turn).
    gyr_std_rad_s : largest rate spread in the window, rad/s, > 0 (default 0.03 rad/s =
        1.7 deg/s, 20x the white noise of a 0.005 deg/s/√Hz gyroscope at 300 Hz).
    acc_std_m_s2 : largest specific-force spread in the window, m/s², > 0 (default 0.15
        m/s²: 3x the noise of a 150 µg/√Hz accelerometer at 300 Hz; raise it for noisier
        accelerometers or higher rates).
    min_duration_s : shortest segment :func:`static_segments` reports, s, >= 0 (default 1).
    """

    window_s: float = 0.5
    max_rate_rad_s: float = 0.1
    gyr_std_rad_s: float = 0.03
    acc_std_m_s2: float = 0.15
    min_duration_s: float = 1.0

    def __post_init__(self) -> None:
        for name in ("window_s", "max_rate_rad_s", "gyr_std_rad_s", "acc_std_m_s2"):
            value = float(getattr(self, name))
            if not (np.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
            object.__setattr__(self, name, value)
        value = float(self.min_duration_s)
        if not (np.isfinite(value) and value >= 0.0):
            raise ValueError(f"min_duration_s must be a finite number >= 0, got {value!r}")
        object.__setattr__(self, "min_duration_s", value)


def _quiet(gyr_sum: Array, gyr_sq: Array, acc_sum: Array, acc_sq: Array, n: float,
           settings: StillnessSettings) -> bool:
    gyr_mean = gyr_sum / n
    gyr_var = np.maximum(gyr_sq / n - gyr_mean * gyr_mean, 0.0).sum()
    acc_mean = acc_sum / n
    acc_var = np.maximum(acc_sq / n - acc_mean * acc_mean, 0.0).sum()
    return bool(
        np.sqrt(gyr_mean @ gyr_mean) <= settings.max_rate_rad_s
        and np.sqrt(gyr_var) <= settings.gyr_std_rad_s
        and np.sqrt(acc_var) <= settings.acc_std_m_s2
    )


class StillnessDetector:
    """Causal stillness test, one sample at a time (for live sources and the guided procedure).

    ``update(t, gyr, acc)`` takes one sample (t in s, gyr (3,) rad/s, acc (3,) m/s²) and
    returns whether the trailing ``window_s`` is quiet. Until the samples seen span
    ``window_s`` it returns False. ``window_start_index`` is the index (counted from the
    first sample given) of the oldest sample in the current window.
    """

    def __init__(self, settings: StillnessSettings | None = None) -> None:
        self.settings = settings or StillnessSettings()
        self._rows: deque[tuple[float, Array, Array]] = deque()
        self._count = 0
        self._t_last = -np.inf
        self._first_t = np.nan
        self._sums = [np.zeros(3) for _ in range(4)]  # gyr, gyr², acc, acc²

    @property
    def window_start_index(self) -> int:
        """Index of the oldest sample in the window (0 before any sample)."""
        return self._count - len(self._rows)

    def update(self, t: float, gyr: ArrayLike, acc: ArrayLike) -> bool:
        """Add one sample; True when the window ending at it is quiet."""
        t = float(t)
        if not t > self._t_last:
            raise ValueError(
                f"timestamps must be strictly increasing: sample {self._count} has t = {t!r} "
                f"after {self._t_last!r}"
            )
        if self._count == 0:
            self._first_t = t
        g = np.asarray(gyr, dtype=np.float64).reshape(3)
        a = np.asarray(acc, dtype=np.float64).reshape(3)
        self._t_last = t
        self._count += 1
        self._rows.append((t, g, a))
        s = self._sums
        s[0] += g
        s[1] += g * g
        s[2] += a
        s[3] += a * a
        window = self.settings.window_s
        # keep exactly the samples within window_s of the newest one
        while self._rows and self._rows[0][0] < t - window:
            _, g_old, a_old = self._rows.popleft()
            s[0] -= g_old
            s[1] -= g_old * g_old
            s[2] -= a_old
            s[3] -= a_old * a_old
        if t - self._first_t < window:
            return False
        return _quiet(s[0], s[1], s[2], s[3], float(len(self._rows)), self.settings)


def _arrays(data: Recording | None, t: ArrayLike | None, gyr: ArrayLike | None,
            acc: ArrayLike | None) -> tuple[Array, Array, Array]:
    if data is not None:
        return data.t, data.gyr, data.acc
    if t is None or gyr is None or acc is None:
        raise ValueError("give a Recording or all of t (N,) s, gyr (N, 3) rad/s, acc (N, 3) m/s²")
    t_arr = np.asarray(t, dtype=np.float64)
    g = np.asarray(gyr, dtype=np.float64)
    a = np.asarray(acc, dtype=np.float64)
    n = t_arr.shape[0]
    if t_arr.ndim != 1 or g.shape != (n, 3) or a.shape != (n, 3):
        raise ValueError(
            f"t must be (N,), gyr and acc (N, 3); got {t_arr.shape}, {g.shape}, {a.shape}"
        )
    bad = np.flatnonzero(np.diff(t_arr) <= 0.0)
    if bad.size:
        raise ValueError(f"timestamps must be strictly increasing: see sample {bad[0] + 1}")
    return t_arr, g, a


def still_mask(
    data: Recording | None = None,
    *,
    t: ArrayLike | None = None,
    gyr: ArrayLike | None = None,
    acc: ArrayLike | None = None,
    settings: StillnessSettings | None = None,
) -> NDArray[np.bool_]:
    """(N,) bool: the trailing window ending at each sample is quiet (module docstring).

    Vectorised with cumulative sums over the same time windows as
    :class:`StillnessDetector`; the two agree except where a statistic sits within
    rounding of its threshold.
    """
    settings = settings or StillnessSettings()
    t_arr, g, a = _arrays(data, t, gyr, acc)
    n = t_arr.shape[0]
    start = np.searchsorted(t_arr, t_arr - settings.window_s, side="left")
    count = (np.arange(n) - start + 1).astype(np.float64)[:, None]

    def window_sum(x: Array) -> Array:
        c = np.vstack([np.zeros((1, 3)), np.cumsum(x, axis=0)])
        return c[np.arange(n) + 1] - c[start]

    def spread(x: Array) -> tuple[Array, Array]:
        mean = window_sum(x) / count
        var = np.maximum(window_sum(x * x) / count - mean * mean, 0.0).sum(axis=1)
        return mean, np.sqrt(var)

    g_mean, g_std = spread(g)
    _, a_std = spread(a)
    mask = (
        (np.linalg.norm(g_mean, axis=1) <= settings.max_rate_rad_s)
        & (g_std <= settings.gyr_std_rad_s)
        & (a_std <= settings.acc_std_m_s2)
    )
    mask &= t_arr - t_arr[0] >= settings.window_s
    return mask


def static_segments(
    data: Recording | None = None,
    *,
    t: ArrayLike | None = None,
    gyr: ArrayLike | None = None,
    acc: ArrayLike | None = None,
    settings: StillnessSettings | None = None,
) -> list[tuple[int, int]]:
    """Still segments as ``(start, stop)`` sample index pairs (``stop`` exclusive).

    A run of still samples ``i0..i1`` (:func:`still_mask`) becomes the segment from the
    first sample of ``i0``'s window to ``i1``; segments shorter than
    ``settings.min_duration_s`` are dropped. Ordered by time, non-overlapping.
    """
    settings = settings or StillnessSettings()
    t_arr, g, a = _arrays(data, t, gyr, acc)
    mask = still_mask(t=t_arr, gyr=g, acc=a, settings=settings)
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    starts = np.flatnonzero(edges == 1)
    stops = np.flatnonzero(edges == -1)
    window_start = np.searchsorted(t_arr, t_arr - settings.window_s, side="left")
    segments: list[tuple[int, int]] = []
    for i0, i1 in zip(starts, stops, strict=True):
        begin = int(window_start[i0])
        if segments and begin < segments[-1][1]:
            begin = segments[-1][1]
        if t_arr[i1 - 1] - t_arr[begin] >= settings.min_duration_s:
            segments.append((begin, int(i1)))
    return segments


def segment_means(values: ArrayLike, segments: list[tuple[int, int]]) -> Array:
    """(K, C) mean of ``values`` (N, C) over each ``(start, stop)`` segment."""
    v = np.asarray(values, dtype=np.float64)
    if v.ndim != 2:
        raise ValueError(f"values must have shape (N, C), got {v.shape}")
    if not segments:
        raise ValueError("no still segment: hold the sensor still (1 s or more) in each pose")
    out = np.empty((len(segments), v.shape[1]))
    for k, (start, stop) in enumerate(segments):
        if not 0 <= start < stop <= v.shape[0]:
            raise ValueError(f"segment {k} ({start}, {stop}) is outside 0..{v.shape[0]}")
        out[k] = v[start:stop].mean(axis=0)
    return out
