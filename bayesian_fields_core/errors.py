"""Error types shared by every stage, so the CLI and the API can turn them into clear messages."""

from __future__ import annotations

import lzma
import struct
import tarfile
import zipfile
import zlib
from typing import Literal


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


class InputErrors(InputError):
    """Several input problems found by one check of a run's inputs, each an InputError naming
    its file and its fix.

    Why one exception: a user should meet every problem of a run at once (not "no tasks given",
    then on the next run "no cameras found"). It is an InputError, so the API answers it with the
    same 4xx; the CLI prints one line per problem (`errors`).
    """

    def __init__(self, errors: list[InputError]) -> None:
        self.errors = list(errors)
        super().__init__(f"{len(self.errors)} problems: " + "; ".join(str(e) for e in self.errors))


def raise_input_errors(errors: list[InputError]) -> None:
    """Raise nothing for no problem, the InputError itself for one, `InputErrors` for several."""
    if len(errors) == 1:
        raise errors[0]
    if errors:
        raise InputErrors(errors)


class InvariantError(BayesianFieldsError, AssertionError):
    """An internal invariant broke: arrays one stage hands another disagree in shape or range.

    Not the user's fault (every input was validated at the edge), so never reported as bad
    input: the CLI says it is a bug and exits 1, and the service records an internal failure.
    """

    def __init__(self, message: str, *, source: str | None = None) -> None:
        self.source = source
        super().__init__(f"{source}: {message}" if source else message)


class ModelError(BayesianFieldsError):
    """A model file the operator configured is missing or unusable."""


class CancelledError(BayesianFieldsError):
    """A job was cancelled; raised between frames when the cancel check fires."""


#: Exception families that mean "this input cannot be parsed or extracted" when they escape a
#: reader: the filesystem refusing a name (ENAMETOOLONG, EEXIST, ENOTDIR), a truncated or corrupt
#: stream (EOFError, zlib / lzma / zip / tar errors), a nested
#: document deeper than the interpreter allows, a binary field that does not unpack, bytes that are
#: not text, an allocation an absurd count asks for, a compression method the library lacks.
INPUT_FAILURES: tuple[type[BaseException], ...] = (
    OSError,
    EOFError,
    RecursionError,
    UnicodeError,
    MemoryError,
    OverflowError,
    ValueError,
    NotImplementedError,
    struct.error,
    zlib.error,
    lzma.LZMAError,
    zipfile.BadZipFile,
    zipfile.LargeZipFile,
    tarfile.TarError,
)


def describe_failure(exc: BaseException) -> str:
    """A short reason for an input failure: an OSError with an errno keeps only its strerror (its
    filename may be a server temp folder), the rest their class name and first 200 chars."""
    if isinstance(exc, RecursionError):
        return "nested too deeply to parse"
    if isinstance(exc, MemoryError):
        return "too large to load (it declares an absurd size or count)"
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror
    text = str(exc)[:200]
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


class input_boundary:  # noqa: N801 - used as a context manager, reads like a statement
    """Turn every INPUT_FAILURES exception raised inside the block into an InputError.

    Why: the readers check what they know about, but a hostile file finds the rest (a recursion
    limit, a struct that does not unpack, a file name the filesystem refuses). At the library's
    boundary every such failure is the input's fault, so the API answers 4xx and the CLI prints
    one line instead of a traceback. InputError itself passes through unchanged.

        with input_boundary("splat.ply", what="cannot read PLY"):
            ...
    """

    def __init__(self, source: str | None, *, what: str = "cannot read input", extra: tuple = ()) -> None:
        self.source = source
        self.what = what
        self.families = INPUT_FAILURES + tuple(extra)

    def __enter__(self) -> input_boundary:
        return self

    def __exit__(self, exc_type, exc, tb) -> Literal[False]:
        if exc is None or isinstance(exc, InputError) or not isinstance(exc, self.families):
            return False
        raise InputError(f"{self.what} ({describe_failure(exc)})", source=self.source) from exc
