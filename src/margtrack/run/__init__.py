"""The one runner: a recording file (any size, read in chunks) through a method to an
estimate file, with flags and, when the recording has truth, scores (``margtrack run``,
``margtrack batch``)."""

from margtrack.run.chunked import FileSummary, run_file

__all__ = ["FileSummary", "run_file"]
