"""Alias of :mod:`tankode.threads` for the library's internal imports."""

from .threads import single_threaded

__all__ = ["single_threaded"]
