"""The error every ingest reader raises for a capture it cannot read."""

from __future__ import annotations


class IngestError(ValueError):
    """A capture that cannot be read; the one-line message names the file and what is wrong."""


def one_line(exc: BaseException) -> str:
    """A library's exception as one short line, for an error message that names the file first."""
    return " ".join(str(exc).split())[:200] or type(exc).__name__
