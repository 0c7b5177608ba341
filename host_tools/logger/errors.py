"""The logger's exceptions."""
from __future__ import annotations


class Stopped(Exception):
    """Raised where a stop request (signal) must end a wait that would otherwise fail."""


class LoggerError(Exception):
    """A problem that ends the recording; ``code`` is the exit code (1 failed, 2 bad input)."""

    def __init__(self, message: str, code: int = 1):
        super().__init__(message)
        self.code = code
