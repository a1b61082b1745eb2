"""Streaming estimate files: write an orientation series chunk by chunk, atomically.

:class:`EstimateWriter` takes the successive :class:`~margtrack.estimator.Estimate` chunks
of one run (the estimator continuing from its state) and writes the file
``margtrack.io.write_estimate`` writes for the whole run, with the same datasets or columns
and the same attributes, while holding one chunk in memory:

- ``.h5``/``.hdf5``: datasets ``t`` (N,) s, ``quat`` (N, 4) ``[w, x, y, z]``, one per
  output (``gyr_bias_rad_s`` ...) and ``flags`` (N,) uint16 (bits of
  :class:`~margtrack.estimator.Flag`), resizable and chunked; attributes ``format``,
  ``version``, ``method``, ``frame`` (the earth frame of ``quat``), ``params`` and
  ``flag_bits`` (see :func:`margtrack.io.hdf5.write_estimate_hdf5`); each dataset has a
  ``unit`` attribute (:mod:`margtrack.io.output_units`);
- ``.csv``: comment lines stating method, frame, parameters and each column's unit, the
  header ``t_s,quat_w,...`` and the rows, appended in blocks (see
  :mod:`margtrack.io.estimate_csv`).

The file is written to a temporary file next to the output and renamed into place by
:meth:`EstimateWriter.close` (:mod:`margtrack.io.safe_output`); an error or an abandoned
writer leaves any previous output untouched.
"""

from __future__ import annotations

from pathlib import Path
from types import TracebackType
from typing import Any

import h5py
import numpy as np

from margtrack.io.estimate_csv import estimate_csv_table
from margtrack.io.hdf5 import (
    estimate_arrays,
    estimate_attrs,
    estimate_outputs,
    write_estimate_attrs,
)
from margtrack.io.output_units import output_unit
from margtrack.io.safe_output import AtomicFile

__all__ = ["EstimateWriter", "estimate_fields"]

HDF5_SUFFIXES = (".h5", ".hdf5")
CSV_SUFFIXES = (".csv",)
#: bytes per HDF5 chunk of a resizable dataset (about 256 KiB: fast appends, small overhead)
_CHUNK_BYTES = 1 << 18


def estimate_fields(estimate: Any) -> tuple[dict[str, Any], dict[str, Any]]:
    """The per-sample outputs (with ``flags``) and the run attributes an estimate file holds.

    Returns ``(outputs, attrs)``: outputs are the Estimate's ``outputs`` then ``flags``
    (bits of :class:`~margtrack.estimator.Flag`); attrs are ``method``, ``frame``,
    ``params`` and ``flag_bits`` (HDF5 only).
    """
    from margtrack.estimator.flags import Flag

    outputs = dict(estimate.outputs)
    flags = getattr(estimate, "flags", None)
    if flags is not None:
        outputs["flags"] = flags
    attrs = {
        "method": estimate.method,
        "frame": estimate.frame,
        "params": dict(estimate.params),
        "flag_bits": {str(f.name): int(f) for f in Flag},
    }
    return outputs, attrs


class EstimateWriter:
    """Write the chunks of one run's estimate to ``path`` (.h5, .hdf5 or .csv), atomically.

    Use as a context manager, or call :meth:`close` (commit) / :meth:`abort` yourself::

        with EstimateWriter("out.h5") as writer:
            for chunk in chunks:
                writer.append(estimator.run(chunk))

    Every chunk must come from the same run: same method, frame, parameters and outputs
    (a ``ValueError`` names what changed). The result equals
    ``margtrack.io.write_estimate(whole_run_estimate, path)`` value for value.
    """

    def __init__(self, path: str | Path) -> None:
        p = Path(path)
        suffix = p.suffix.lower()
        if suffix in HDF5_SUFFIXES:
            self.kind = "hdf5"
        elif suffix in CSV_SUFFIXES:
            self.kind = "csv"
        else:
            raise ValueError(
                f"cannot write {p}: unsupported extension {p.suffix!r}; use one of "
                f"{', '.join((*HDF5_SUFFIXES, *CSV_SUFFIXES))}"
            )
        self.path = p
        self.n_samples = 0
        self._target = AtomicFile(p)
        self._h5: h5py.File | None = None
        self._text: Any = None
        self._columns: list[str] | None = None
        self._header = ""
        self._layout: dict[str, tuple[tuple[int, ...], np.dtype[Any]]] | None = None
        self._attrs: dict[str, Any] | None = None

    # -- context manager -----------------------------------------------------------------
    def __enter__(self) -> EstimateWriter:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    # -- writing -------------------------------------------------------------------------
    def append(self, estimate: Any) -> None:
        """Append the samples of the next chunk (an Estimate of one sensor)."""
        if self._target.done:
            raise ValueError(f"the writer of {self.path} is closed")
        if np.ndim(estimate.quat) != 2:
            raise ValueError(
                f"{self.path}: an estimate file holds one sensor; the estimate has quat of "
                f"shape {np.shape(estimate.quat)}: write each sensor to its own file"
            )
        outputs, attrs = estimate_fields(estimate)
        try:
            if self.kind == "hdf5":
                self._append_hdf5(estimate, outputs, attrs)
            else:
                self._append_csv(estimate, outputs)
        except BaseException:
            self.abort()
            raise
        self.n_samples += int(np.shape(estimate.t)[0])

    def _append_hdf5(
        self, estimate: Any, outputs: dict[str, Any], attrs: dict[str, Any]
    ) -> None:
        t, q = estimate_arrays(estimate.t, estimate.quat)
        n = t.shape[0]
        arrays = {"t": t, "quat": q, **estimate_outputs(outputs, n)}
        layout = {k: (v.shape[1:], v.dtype) for k, v in arrays.items()}
        if self._h5 is None:
            plain, as_json = estimate_attrs(attrs)  # checked before the file is created
            f = self._h5 = h5py.File(self._target.tmp, "w")
            write_estimate_attrs(f, plain, as_json)
            for name, (shape, dtype) in layout.items():
                row_bytes = max(1, int(np.prod(shape, dtype=np.int64)) * dtype.itemsize)
                # about _CHUNK_BYTES per chunk, less when the first piece is short (a short
                # run written at once stays a small file)
                rows = max(1, min(_CHUNK_BYTES // row_bytes, 1 << 16, max(n, 1024)))
                dataset = f.create_dataset(
                    name, shape=(0, *shape), maxshape=(None, *shape), dtype=dtype,
                    chunks=(rows, *shape),
                )
                dataset.attrs["unit"] = output_unit(name, dtype)
            self._layout, self._attrs = layout, attrs
        else:
            self._same_run(layout, attrs)
        f = self._h5
        start = self.n_samples
        for name, value in arrays.items():
            dataset = f[name]
            dataset.resize(start + n, axis=0)
            dataset[start : start + n] = value

    def _append_csv(self, estimate: Any, outputs: dict[str, Any]) -> None:
        table = estimate_csv_table(
            estimate.t, estimate.quat, outputs, method=estimate.method, frame=estimate.frame,
            params=dict(estimate.params),
        )
        header = table.header()
        if self._text is None:
            self._text = self._target.tmp.open("w", encoding="utf-8")
            self._text.write(header)
            self._columns, self._header = list(table.names), header
        elif table.names != self._columns:
            raise ValueError(
                f"{self.path}: this chunk has columns {table.names}, the file has "
                f"{self._columns}; every chunk must come from the same run"
            )
        elif header != self._header:
            raise ValueError(
                f"{self.path}: this chunk states another method, frame or parameters than "
                "the file's first chunk; every chunk must come from the same run"
            )
        for text in table.row_blocks():
            self._text.write(text)

    def _same_run(
        self, layout: dict[str, tuple[tuple[int, ...], np.dtype[Any]]], attrs: dict[str, Any]
    ) -> None:
        if layout != self._layout:
            raise ValueError(
                f"{self.path}: this chunk has outputs {_describe(layout)}, the file has "
                f"{_describe(self._layout or {})}; every chunk must come from the same run"
            )
        assert self._attrs is not None
        for key in ("method", "frame", "params"):
            if attrs[key] != self._attrs[key]:
                raise ValueError(
                    f"{self.path}: this chunk has {key} {attrs[key]!r}, the file has "
                    f"{self._attrs[key]!r}; every chunk must come from the same run"
                )

    # -- finishing -----------------------------------------------------------------------
    def close(self) -> None:
        """Finish the file and rename it onto the output (replacing an existing one)."""
        if self._target.done:
            return
        if self.n_samples == 0:
            self.abort()
            raise ValueError(f"no samples were appended: {self.path} was not written")
        try:
            self._close_handles()
        except BaseException:
            self._target.discard()
            raise
        self._target.commit()

    def abort(self) -> None:
        """Give up: remove the temporary file; an existing output stays as it was."""
        try:
            self._close_handles()
        except OSError:
            pass
        finally:
            self._target.discard()

    def _close_handles(self) -> None:
        h5, text = self._h5, self._text
        self._h5 = self._text = None
        if h5 is not None:
            h5.close()
        if text is not None:
            text.close()


def _describe(layout: dict[str, tuple[tuple[int, ...], np.dtype[Any]]]) -> str:
    return ", ".join(f"{k} {shape} {dtype}" for k, (shape, dtype) in layout.items())
