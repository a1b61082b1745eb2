from margtrack import frames, quaternion
from margtrack.recording import Recording

__version__ = "0.1.0"
__all__ = ["Recording", "frames", "quaternion"]
