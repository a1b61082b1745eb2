"""Error metrics and benchmark runners (BROAD, speed)."""

from margtrack.bench import metrics

__all__ = ["metrics"]
