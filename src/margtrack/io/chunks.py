"""A recording file as successive chunks: long margtrack HDF5 files never loaded whole.

:func:`open_chunks` gives a :class:`RecordingChunks` whose iteration yields
``(first_sample, Recording)`` pairs of at most ``chunk_samples`` samples, in SI units:

- a margtrack HDF5 recording (layout of :mod:`margtrack.io.hdf5`) is read a chunk at a
  time with h5py slices; each chunk is checked like a whole file (finite values, strictly
  increasing timestamps, also across chunk boundaries) with the sample numbers of the
  whole file in the messages, and converted from the declared units (as :func:`read`);
- anything else :func:`margtrack.io.read` reads (CSV, BROAD, x-IMU3) is read whole and
  sliced; ``whole`` then holds that Recording.

Used by :func:`margtrack.run.chunked.run_file` (``margtrack run`` and ``batch``).
"""

from __future__ import annotations

import json
from collections.abc import Iterator, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any

import h5py
import numpy as np

from margtrack.io import hdf5
from margtrack.recording import Recording
from margtrack.units import UnitError, convert_unit, unit_factor

__all__ = ["RecordingChunks", "open_chunks"]

_FIELDS = ("t", "gyr", "acc", "mag", "quat_true", "movement")
_UNITS = ("gyr_unit", "acc_unit", "mag_unit", "time_unit")


class _Slice:
    """Samples ``start:stop`` of one dataset, read when NumPy converts it to an array.

    The Recording constructor copies its inputs (``np.array``); handing it this instead of
    an array read beforehand keeps one copy of a chunk in memory instead of two (NumPy 2
    asks ``__array__`` for a copy, and a freshly read array is one).
    """

    def __init__(self, source: RecordingChunks, name: str, start: int, stop: int) -> None:
        self.source, self.name, self.start, self.stop = source, name, start, stop

    def __array__(self, dtype: Any = None, copy: bool | None = None) -> np.ndarray:
        arr = self.source._read(self.name, self.start, self.stop)
        return arr if dtype is None else arr.astype(dtype, copy=False)


class RecordingChunks:
    """One recording file, iterated as ``(first_sample, Recording)`` chunks.

    Attributes
    ----------
    path : the file. n_samples : N of the whole file. chunk_samples : samples per chunk.
    whole : the Recording read whole (formats other than margtrack HDF5), else None.
    """

    def __init__(
        self, path: Path, chunk_samples: int, whole: Recording | None = None,
        f: h5py.File | None = None, units: dict[str, str | None] | None = None,
    ) -> None:
        if int(chunk_samples) < 1:
            raise ValueError(f"chunk_samples must be at least 1, got {chunk_samples}")
        self.path, self.chunk_samples, self.whole, self._f = path, int(chunk_samples), whole, f
        self._units = {k.removesuffix("_unit"): v for k, v in (units or {}).items()}
        if whole is not None:
            self.n_samples = whole.n_samples
            return
        assert f is not None
        fmt = f.attrs.get("format")
        if fmt != hdf5.RECORDING_FORMAT:
            raise ValueError(
                f"{path} is not a margtrack recording: attribute format is {fmt!r}, expected "
                f"{hdf5.RECORDING_FORMAT!r}"
            )
        version = int(f.attrs.get("version", -1))
        if version != hdf5.VERSION:
            raise ValueError(
                f"{path} has margtrack recording version {version}; this margtrack reads "
                f"{hdf5.VERSION}"
            )
        missing = [k for k in ("t", "gyr", "acc") if k not in f]
        if missing:
            raise ValueError(f"{path} has no dataset {missing[0]!r}; it has {sorted(f.keys())}")
        self._names = [k for k in _FIELDS if k in f]
        n = int(f["t"].shape[0]) if len(f["t"].shape) == 1 else -1
        for name in self._names:
            shape = f[name].shape
            if n < 0 or shape[:1] != (n,):
                raise ValueError(
                    f"{path}: dataset {name!r} has shape {shape} but t has {f['t'].shape}; "
                    "every dataset needs one row per timestamp"
                )
        if n == 0:
            raise ValueError(f"{path} holds no samples")
        self.n_samples = n
        self._frame = str(f.attrs.get("frame", ""))
        self._name = str(f.attrs.get("name", ""))
        try:
            self._meta = json.loads(str(f.attrs.get("meta", "{}")))
        except json.JSONDecodeError as exc:
            raise ValueError(f"{path}: attribute meta is not valid JSON: {exc}") from None

    # -- context manager -----------------------------------------------------------------
    def __enter__(self) -> RecordingChunks:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def close(self) -> None:
        """Close the file (nothing to do for a recording read whole)."""
        if self._f is not None:
            self._f.close()
            self._f = None

    # -- chunks ----------------------------------------------------------------------------
    def __iter__(self) -> Iterator[tuple[int, Recording]]:
        if self.whole is not None:
            for start in range(0, self.n_samples, self.chunk_samples):
                yield start, self.whole.slice(start, start + self.chunk_samples)
            return
        t_prev = float("nan")
        for start in range(0, self.n_samples, self.chunk_samples):
            stop = min(start + self.chunk_samples, self.n_samples)
            # the Recording reads each dataset slice as it copies it: one copy in memory
            fields = {name: _Slice(self, name, start, stop) for name in self._names}
            try:
                rec = Recording(frame=self._frame, name=self._name, meta=self._meta, **fields)
            except UnitError:
                raise
            except ValueError as exc:
                # say where in the whole file, if it is a bad value or timestamp
                self._check({n: self._read(n, start, stop) for n in self._names}, start, t_prev)
                raise ValueError(
                    f"{self.path}: {exc} (in the chunk from sample {start}: sample numbers "
                    "count from there)"
                ) from None
            if start:
                self._check({"t": rec.t[:1]}, start, t_prev)  # across the chunk boundary
            t_prev = float(rec.t[-1])
            if any(unit is not None for unit in self._units.values()):
                try:
                    rec = rec.with_units(**self._units)
                except ValueError as exc:
                    raise ValueError(f"{self.path}: {exc}") from None
            yield start, rec
            del rec

    def _read(self, name: str, start: int, stop: int) -> np.ndarray:
        if self._f is None:
            raise ValueError(f"{self.path} is closed")
        try:
            return np.asarray(self._f[name][start:stop])
        except (OSError, RuntimeError, ValueError) as exc:
            raise ValueError(
                f"{self.path}: cannot read samples {start} to {stop - 1} of dataset {name!r} "
                f"({exc}); the file is damaged or truncated"
            ) from None

    def _check(self, fields: dict[str, np.ndarray], start: int, t_prev: float) -> None:
        """Non-finite values and non-increasing timestamps, by sample number of the file."""
        for name in ("t", "gyr", "acc", "mag", "quat_true"):
            if name not in fields:
                continue
            value = np.asarray(fields[name], dtype=np.float64)
            bad = ~np.isfinite(value)
            if bad.any():
                row = int(np.argwhere(bad)[0][0])
                raise ValueError(
                    f"{self.path}: {name} has a non-finite value (NaN or inf) at sample "
                    f"{start + row}: {value[row]}; remove or interpolate it first"
                )
        t = np.asarray(fields["t"], dtype=np.float64)
        full = t if start == 0 else np.concatenate([[t_prev], t])
        offset = start if start == 0 else start - 1  # sample number of full[0]
        bad_steps = np.flatnonzero(~(np.diff(full) > 0.0))
        if bad_steps.size:
            j = int(bad_steps[0])
            i = offset + j + 1
            before, after = float(full[j]), float(full[j + 1])
            kind = "duplicate" if after == before else "non-monotonic"
            raise ValueError(
                f"{self.path}: {kind} timestamp at sample {i}: t[{i - 1}] = {before!r}, "
                f"t[{i}] = {after!r}; timestamps must be strictly increasing seconds"
            )

    def rate_hz(self) -> float:
        """Median sample rate of the whole file, Hz (as :attr:`Recording.rate_hz`)."""
        if self.whole is not None:
            return self.whole.rate_hz
        if self.n_samples < 2:
            return float("nan")
        steps = np.empty(self.n_samples - 1)
        previous: float | None = None
        for start in range(0, self.n_samples, self.chunk_samples):
            t = self._read("t", start, min(start + self.chunk_samples, self.n_samples))
            t = np.asarray(t, dtype=np.float64)
            if self._units.get("time") is not None:
                t = convert_unit(t, "time", str(self._units["time"]))
            joined = t if previous is None else np.concatenate([[previous], t])
            first = 0 if previous is None else start - 1
            steps[first : first + joined.shape[0] - 1] = np.diff(joined)
            previous = float(t[-1])
        return float(1.0 / np.median(steps, overwrite_input=True))


def open_chunks(
    path: str | Path | Sequence[str | Path], chunk_samples: int = 1_000_000, **read_kwargs: Any
) -> RecordingChunks:
    """The recording at ``path`` as chunks of ``chunk_samples`` samples (module docstring).

    A list of per-sensor files (one sensor type each) is read whole by
    :func:`margtrack.io.read`, merged onto the gyroscope's timestamps.

    ``read_kwargs`` are those of :func:`margtrack.io.read`; a margtrack HDF5 file takes only
    the unit declarations (``gyr_unit``, ``acc_unit``, ``mag_unit``, ``time_unit``).
    Raises ``ValueError`` naming the file for an unreadable (truncated, damaged) HDF5 file.
    """
    if not isinstance(path, str | Path):  # per-sensor files, merged when read (io.read)
        from margtrack import io

        files = [Path(x) for x in path]
        return RecordingChunks(files[0], chunk_samples, whole=io.read(files, **read_kwargs))
    p = Path(path)
    if p.suffix.lower() in (".h5", ".hdf5") and p.is_file():
        try:
            f = h5py.File(p, "r")
        except OSError as exc:
            raise ValueError(
                f"{p} is not a readable HDF5 file ({exc}); it may be truncated or damaged"
            ) from None
        # margtrack recordings are read in chunks; other HDF5 layouts (BROAD trials, which
        # are short) are read whole below
        if f.attrs.get("format") == hdf5.RECORDING_FORMAT and "imu_gyr" not in f:
            try:
                given = {k for k, v in read_kwargs.items() if v is not None}
                unknown = sorted(given - set(_UNITS))
                if unknown:
                    raise ValueError(
                        f"{p} is a margtrack HDF5 recording; the reader options {unknown} do "
                        "not apply to it (only gyr_unit, acc_unit, mag_unit and time_unit do)"
                    )
                units = {k: read_kwargs.get(k) for k in _UNITS}
                for arg, unit in units.items():
                    if unit is not None:
                        unit_factor(arg.removesuffix("_unit"), unit)  # unknown units fail now
                return RecordingChunks(p, chunk_samples, f=f, units=units)
            except BaseException:
                f.close()
                raise
        f.close()
    from margtrack import io

    return RecordingChunks(p, chunk_samples, whole=io.read(p, **read_kwargs))
