"""gaintune: reinforcement-learning gain tuning for cascaded PID and LQ loops, with verification."""

__version__ = "0.1.0"
