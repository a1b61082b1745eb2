"""Error metrics and benchmark runners (BROAD, speed)."""

from margtrack import accuracy as metrics

__all__ = ["metrics"]
