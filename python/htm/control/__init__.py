"""The real-time control loop around the Rust controller, its safety (limit detectors, actions,
interlocks, e-stop), timing statistics, and the operator-facing `Session`."""
from htm.control.session import Session

__all__ = ["Session"]
