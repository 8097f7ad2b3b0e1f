"""qr: learn what a quadrotor's physics model gets wrong from measured flight logs."""

__version__ = "0.1.0"
