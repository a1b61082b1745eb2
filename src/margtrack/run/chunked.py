"""One recording file to one estimate file in bounded memory: read, run and write in chunks.

:func:`run_file` is the per-file work of ``margtrack run`` and ``margtrack batch``. The
estimator runs chunk after chunk, continuing from its state (the contract: two half runs
equal one run, to 1e-12), the estimate is streamed to the output
(:class:`~margtrack.io.estimate_writer.EstimateWriter`), and the figures of the whole run
(samples, gaps, flags, error RMSE against the truth) are accumulated chunk by chunk, so a
10-million-sample recording never sits in memory whole:

- margtrack HDF5 recordings are read a chunk at a time (h5py slices); every chunk is
  validated (finite values, increasing timestamps, also across chunk boundaries) with the
  sample numbers of the whole file in the messages;
- other formats (CSV, BROAD, x-IMU3) are read whole by :func:`margtrack.io.read` and then
  run and written in chunks.

The output is checked before anything is computed (:func:`~margtrack.io.safe_output.check_output`:
never the input, an existing file only with ``force``) and written atomically.

RMSE figures come from the one runner's :class:`~margtrack.bench.runner.ErrorAccumulator`
(BROAD convention: errors of ``e = q_est ⊗ q_true*`` over the ``movement`` samples, truth
holes skipped), fed chunk by chunk: the same code and figures as
:func:`margtrack.bench.runner.score` on the whole run.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from margtrack.accuracy import ErrorAccumulator
from margtrack.estimator.flags import FAULT_FLAGS, Flag, format_summary
from margtrack.io.chunks import open_chunks
from margtrack.io.mapped import flag_invalid
from margtrack.io.safe_output import check_output
from margtrack.recording import Recording, Saturation, find_saturation
from margtrack.units import UnitError, check_unit_magnitudes

__all__ = ["FileSummary", "FlagTally", "run_file"]

#: fields of :meth:`FileSummary.as_row`, in order
ROW_FIELDS = (
    "file", "samples", "duration_s", "rate_hz", "method", "gaps", "fault_samples",
    "rest_samples", "initialising_samples", "mag_ignored_pct", "total_rmse_deg",
    "heading_rmse_deg", "inclination_rmse_deg", "seconds",
)
#: the chunk size of an offline method: the whole recording (its memory grows with it)
_WHOLE = 2**62

#: samples run and written at a time within a chunk
_RUN_BLOCK = 1 << 18


@dataclass(frozen=True)
class FileSummary:
    """What one :func:`run_file` did, for one line of a report or one row of a table.

    file : the input path. samples : N. duration_s : last minus first timestamp, s.
    rate_hz : median sample rate, Hz (as :attr:`Recording.rate_hz`; nan for one sample).
    method : the estimator's registered name (``"default"`` resolved).
    gaps : number of gaps (samples flagged GAP: each is the first sample after a gap).
    fault_samples : samples with a fault flag (:data:`~margtrack.estimator.flags.FAULT_FLAGS`:
        input faults and rejected disturbances); 0 for clean data.
    rest_samples, initialising_samples : samples in the states REST and INITIALISING
        (normal, not faults).
    mag_ignored_pct : share of samples whose magnetometer was not used (MAG_IGNORED or
        MAG_DISTURBED), percent.
    total_rmse_deg, heading_rmse_deg, inclination_rmse_deg : error RMSE against the truth
        over the ``movement`` samples, deg; None without truth (or without movement).
    seconds : wall time of the whole call (read, run, write), s.
    output : the estimate file written. frame : the earth frame of its ``quat``.
    flag_summary : the one-line flag summary (as :func:`margtrack.estimator.flags.summary`).
    warnings : sensors found at their range limit, one sentence each.
    """

    file: str
    samples: int
    duration_s: float
    rate_hz: float
    method: str
    gaps: int
    fault_samples: int
    rest_samples: int
    initialising_samples: int
    mag_ignored_pct: float
    total_rmse_deg: float | None
    heading_rmse_deg: float | None
    inclination_rmse_deg: float | None
    seconds: float
    output: str = ""
    frame: str = ""
    flag_summary: str = ""
    warnings: tuple[str, ...] = field(default=())

    def as_row(self) -> dict[str, Any]:
        """The figures as one table row (the fields of ``ROW_FIELDS``, in that order)."""
        values = asdict(self)
        return {key: values[key] for key in ROW_FIELDS}


class FlagTally:
    """Health flags of one sensor counted chunk by chunk: per bit, the count and first sample.

    :meth:`text` is :func:`margtrack.estimator.flags.summary` of all the flags seen.
    """

    def __init__(self) -> None:
        self.total = 0
        #: samples with a fault flag (:data:`~margtrack.estimator.flags.FAULT_FLAGS`)
        self.faulty = 0
        self.counts = {f: 0 for f in Flag}
        self.first: dict[Flag, int] = {}

    def add(self, flags: np.ndarray) -> None:
        """Count the next chunk's flags (N,) uint16."""
        arr = np.asarray(flags).astype(np.uint16, copy=False)
        self.faulty += int(np.count_nonzero(arr & int(FAULT_FLAGS)))
        for f in Flag:
            hits = (arr & int(f)) != 0
            n = int(np.count_nonzero(hits))
            if n:
                self.counts[f] += n
                self.first.setdefault(f, self.total + int(np.argmax(hits)))
        self.total += arr.shape[0]

    def text(self) -> str:
        """``"faults: 12 of 9000 samples (0.13 %): GAP 1 (first at sample 4500), ...;
        states: REST ..."``."""
        return format_summary(
            self.total, self.faulty, self.counts,
            {f: f"sample {i}" for f, i in self.first.items()},
        )


def _saturation_text(name: str, hit: Saturation) -> str:
    advice = (
        "remove the magnet or metal near the sensor" if name == "mag"
        else "choose a wider sensor range"
    )
    return (
        f"{name} sits at its range limit ±{hit.level:.4g} from sample {hit.first_sample} "
        f"({hit.n_samples} samples); estimates there are unreliable: {advice}"
    )


def _unit_fix(signal: str, suspected: str) -> str:
    return (
        f"declare the file's unit (--{signal}-unit {suspected} on the command line, "
        f"read_kwargs={{'{signal}_unit': '{suspected}'}} in Python)"
    )


def _check_units(rec: Recording, source: str, start: int = 0) -> None:
    try:
        check_unit_magnitudes(rec.gyr, rec.acc, fix=_unit_fix, t_s=rec.t)
    except UnitError as exc:
        where = f" (in the chunk from sample {start}; sample numbers count from there)"
        raise UnitError(
            f"{source}: {exc}{where if start else ''}", signal=exc.signal,
            suspected=exc.suspected, fix=exc.fix,
        ) from None


def _load_calibration(calibration: Any) -> Any:
    if calibration is None or hasattr(calibration, "apply"):
        return calibration
    from margtrack.calibration import load_calibration

    return load_calibration(calibration)


def run_file(
    input_path: str | Path | Sequence[str | Path],
    output_path: str | Path,
    method: str = "default",
    params: Iterable[str] | Mapping[str, Any] = (),
    *,
    calibration: Any = None,
    frame: str | None = None,
    read_kwargs: Mapping[str, Any] | None = None,
    chunk_samples: int = 1_000_000,
    force: bool = False,
    progress: Callable[[int, int], None] | None = None,
    on_warning: Callable[[str], None] | None = None,
) -> FileSummary:
    """Estimate the orientation of one recording file and write it, in chunks.

    Parameters
    ----------
    input_path : a recording :func:`margtrack.io.read` can read (margtrack HDF5 is read
        chunk by chunk; other formats whole), or a list of per-sensor files (one sensor
        type each, merged onto the gyroscope's timestamps by
        :func:`margtrack.io.read_sensor_files`).
    output_path : the estimate file, ``.h5``/``.hdf5`` or ``.csv`` (as
        :func:`margtrack.io.write_estimate`); checked before any computation.
    method : registered method name (``"default"``: the recommended one).
    params : parameters as ``name=value`` strings or a mapping; they win over the
        calibration's.
    calibration : a calibration JSON path or a loaded ``Calibration``, applied to every
        chunk; the parameters it calibrates are set first.
    frame : earth frame of the written orientation ("NED"/"ENU"; None: the method's).
    read_kwargs : keywords for the reader (``gyr_unit``, ``acc_unit``, ``mag_unit``,
        ``time_unit``; more for CSV, as :func:`margtrack.io.read`).
    chunk_samples : samples per chunk (bounds the memory: about 0.3 KB per sample); an
        offline method (``smoother``) reads and runs the whole recording at once.
    force : replace an existing output (never the input).
    progress : ``progress(samples_done, samples_total)`` after each chunk.
    on_warning : called with each warning sentence as it is found (also in the summary).

    Returns
    -------
    The :class:`FileSummary` of the run.

    Raises
    ------
    ValueError, FileExistsError, FileNotFoundError, PermissionError : bad output (before
        any computation), unreadable or invalid input (naming the file and the sample).
    """
    started = time.perf_counter()
    if int(chunk_samples) < 1:
        raise ValueError(f"chunk_samples must be at least 1, got {chunk_samples}")
    from margtrack import methods
    from margtrack.io.estimate_writer import EstimateWriter

    inputs = _inputs(input_path)
    out = Path(output_path)
    check_output(out, inputs, force=force)
    for src in inputs:
        if not src.exists():
            raise FileNotFoundError(f"no such file or folder: {src}")
    src_text = ", ".join(map(str, inputs))
    cal = _load_calibration(calibration)
    cls = methods.get(method)
    values: dict[str, Any] = {} if cal is None else dict(cal.parameter_values(cls.params_type))
    values.update(params if isinstance(params, Mapping) else methods.parse_params_items(params))
    estimator = methods.create(method, values)
    # an offline method smooths the whole recording at once: one chunk, one block
    whole_file = bool(getattr(cls, "offline", False))
    if whole_file:
        chunk_samples = _WHOLE
    kwargs = dict(read_kwargs or {})
    warned: list[str] = []
    saturation: dict[str, Saturation] = {}
    tally, errors = FlagTally(), ErrorAccumulator()
    gaps = mag_ignored = 0
    t_first = t_last = float("nan")
    out_frame = ""

    def warn(text: str) -> None:
        warned.append(text)
        if on_warning is not None:
            on_warning(text)

    # the writer first: an unsupported output extension fails before the input is read
    source_path: Path | list[Path] = inputs[0] if len(inputs) == 1 else inputs
    with EstimateWriter(out) as writer, open_chunks(
        source_path, int(chunk_samples), **kwargs
    ) as source:
        whole = source.whole
        if whole is not None:
            _check_units(whole, src_text)
            for name, hit in whole.saturation().items():
                warn(_saturation_text(name, hit))
        for start, chunk in source:
            if whole is None:
                _check_units(chunk, src_text, start)
                _merge_saturation(saturation, chunk, start)
            block = chunk.n_samples if whole_file else _RUN_BLOCK
            for first in range(0, chunk.n_samples, block):
                # run and write a block at a time: the outputs of a whole chunk (some 100
                # bytes per sample) never sit in memory beside it
                piece = chunk.slice(first, first + block)
                if cal is not None:
                    piece = cal.apply(piece)
                estimate = estimator.run(piece, check_units=False)  # checked per chunk above
                # samples a reader held over an empty cell: flagged INVALID (io.mapped)
                estimate = flag_invalid(estimate, piece, start + first)
                if frame is not None:
                    estimate = estimate.in_frame(frame)
                writer.append(estimate)
                out_frame = estimate.frame
                flags = estimate.flags
                if flags is not None:
                    tally.add(flags)
                    gaps += int(np.count_nonzero(flags & int(Flag.GAP)))
                    mag_ignored += int(
                        np.count_nonzero(flags & int(Flag.MAG_IGNORED | Flag.MAG_DISTURBED))
                    )
                errors.add(piece, estimate.quat, estimate.frame)
                del estimate, piece
            if start == 0:
                t_first = float(chunk.t[0])
            t_last = float(chunk.t[-1])
            del chunk
            if progress is not None:
                progress(min(start + int(chunk_samples), source.n_samples), source.n_samples)
        for name, hit in saturation.items():
            warn(_saturation_text(name, hit))
        n = source.n_samples
        rate_hz = source.rate_hz()
    total, heading, inclination = errors.rmse_deg()
    return FileSummary(
        file=src_text,
        samples=n,
        duration_s=t_last - t_first,
        rate_hz=float(rate_hz),
        method=estimator.name,
        gaps=gaps,
        fault_samples=tally.faulty,
        rest_samples=tally.counts[Flag.REST],
        initialising_samples=tally.counts[Flag.INITIALISING],
        mag_ignored_pct=100.0 * mag_ignored / n if n else 0.0,
        total_rmse_deg=total,
        heading_rmse_deg=heading,
        inclination_rmse_deg=inclination,
        seconds=time.perf_counter() - started,
        output=str(out),
        frame=out_frame,
        flag_summary=tally.text(),
        warnings=tuple(warned),
    )


def _inputs(input_path: str | Path | Sequence[str | Path]) -> list[Path]:
    """The input as a non-empty list of paths (one file or folder, or per-sensor files)."""
    if isinstance(input_path, str | Path):
        return [Path(input_path)]
    paths = [Path(p) for p in input_path]
    if not paths:
        raise ValueError("no input file: give a recording, or per-sensor files")
    return paths


def _merge_saturation(found: dict[str, Saturation], chunk: Recording, start: int) -> None:
    """Add a chunk's range-limit hits (sample numbers of the whole file) to ``found``."""
    for name in ("gyr", "acc", "mag"):
        values = getattr(chunk, name)
        hit = None if values is None else find_saturation(values)
        if hit is None:
            continue
        old = found.get(name)
        if old is None:
            found[name] = Saturation(start + hit.first_sample, hit.n_samples, hit.level)
        else:
            found[name] = Saturation(
                old.first_sample, old.n_samples + hit.n_samples, max(old.level, hit.level)
            )
