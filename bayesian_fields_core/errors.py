"""Error types shared by every stage, so the CLI and the API can turn them into clear messages."""

from __future__ import annotations


class BayesianFieldsError(Exception):
    """Base class for every error this library raises on purpose."""


class InputError(BayesianFieldsError, ValueError):
    """Bad user input: a malformed file, a wrong field, a limit exceeded.

    The message always names the file (or field) and the problem; the API maps this to a 4xx
    response and the CLI prints it without a traceback.
    """

    def __init__(self, message: str, *, source: str | None = None) -> None:
        self.source = source
        super().__init__(f"{source}: {message}" if source else message)


class ModelError(BayesianFieldsError):
    """A model file the operator configured is missing or unusable."""


class CancelledError(BayesianFieldsError):
    """A job was cancelled; raised between frames when the cancel check fires."""
