"""The ARVA receiver wire protocol: $PARVA / $PARVH sentences (Python and C99)."""

__version__ = "0.1.0"
