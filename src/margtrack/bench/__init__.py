"""Error metrics and benchmark runners (BROAD, speed)."""
