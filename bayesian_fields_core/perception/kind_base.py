"""What a model kind is: a typed profile section that knows how to build its model.

A profile's ``segmenter`` and ``encoder`` sections are discriminated on ``kind``: each kind is one
pydantic class (a subclass of :class:`SegmenterConfig` or :class:`EncoderConfig`) registered with
``@SEGMENTERS.register`` / ``@ENCODERS.register``. The class carries everything about the kind in
one place: its typed ``params`` (unknown keys refused when the profile is read, not when a
constructor fails), its factory (``build``, returning the ``Segmenter`` / ``Encoder`` protocol)
and, for an encoder, the rule that computes its ``model_id`` from its files without loading it.
Adding a kind is adding one such class; nothing else dispatches on kind names.

Fields are tagged with their role instead of being listed by name elsewhere: a ``ModelFile`` is
resolved against the profile's folder and hashed (by content) into the perception fingerprint; a
``Runtime`` setting (device, threads, batch size) does not change the output, so the fingerprint
leaves it out.
"""

from __future__ import annotations

import abc
import difflib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Generic, TypeVar

from pydantic import BaseModel, ConfigDict, ValidationError
from pydantic_core import InitErrorDetails, PydanticCustomError

from bayesian_fields_core.perception.digest import files_digest

if TYPE_CHECKING:
    from typing import Self

    from bayesian_fields_core.perception.encoder import Encoder
    from bayesian_fields_core.perception.segmenter import Segmenter


@dataclass(frozen=True)
class _Role:
    """Annotation metadata saying what a field is to the profile machinery."""

    name: str


MODEL_FILE = _Role("model file")
RUNTIME = _Role("runtime")

T = TypeVar("T")
#: A path to a model file or folder: resolved against the profile's folder, hashed in the fingerprint.
ModelFile = Annotated[str, MODEL_FILE]
#: A setting that does not change the output (device, threads, batch size): not in the fingerprint.
Runtime = Annotated[T, RUNTIME]


def _has_role(model: type[BaseModel], name: str, role: _Role) -> bool:
    return role in model.model_fields[name].metadata


def resolve_path(value: str, base: Path) -> str:
    """``value`` as an absolute path, a relative one taken from ``base`` (the profile's folder)."""
    p = Path(value).expanduser()
    return str(p if p.is_absolute() else (base / p).resolve())


class KindParams(BaseModel):
    """A kind's keyword arguments, typed. Fields left unset are not passed on, so the model
    class's own signature holds the defaults (written once, there); a field's ``None`` default
    here only means "not given"."""

    model_config = ConfigDict(extra="forbid")

    def kwargs(self) -> dict[str, Any]:
        """The keyword arguments the profile sets (explicit ``null`` included)."""
        return self.model_dump(exclude_unset=True)

    def identity(self) -> dict[str, Any]:
        """The set arguments that change the output: model files by content, runtime ones left out."""
        cls = type(self)
        return {
            k: files_digest([v]) if _has_role(cls, k, MODEL_FILE) and isinstance(v, str) else v
            for k, v in self.kwargs().items()
            if not _has_role(cls, k, RUNTIME)
        }

    def model_files(self) -> list[str]:
        """The set ``ModelFile`` values (paths of model files)."""
        cls = type(self)
        return [v for k, v in self.kwargs().items() if _has_role(cls, k, MODEL_FILE) and isinstance(v, str)]

    def resolved(self, base: Path) -> Self:
        """A copy with its ``ModelFile`` fields resolved against ``base``."""
        cls = type(self)
        update = {
            k: resolve_path(v, base)
            for k, v in self.kwargs().items()
            if _has_role(cls, k, MODEL_FILE) and isinstance(v, str)
        }
        return self.model_copy(update=update)


class NoParams(KindParams):
    """For a kind that takes no keyword arguments."""


class SegmenterConfig(BaseModel, abc.ABC):
    """A profile's ``segmenter`` section; subclasses fix ``kind`` to a literal and type ``params``."""

    model_config = ConfigDict(extra="forbid")
    kind: str
    params: KindParams

    @abc.abstractmethod
    def build(self, *, device: str | None = None) -> Segmenter:
        """The segmenter (``device``, when given, overrides a device in ``params``)."""

    def describe(self) -> str:
        """Its model files by name, for a log line ("" when it has none)."""
        return ", ".join(Path(f).name for f in self.params.model_files())

    def identity(self) -> dict[str, Any]:
        """What of this section changes the masks (for the perception fingerprint)."""
        return {"kind": self.kind, "params": self.params.identity()}

    def resolved(self, base: Path) -> Self:
        """A copy whose model files are absolute (relative ones taken from ``base``)."""
        return self.model_copy(update={"params": self.params.resolved(base)})


class EncoderConfig(BaseModel, abc.ABC):
    """A profile's ``encoder`` section: ``path`` (the model's folder or file), ``device`` and the
    kind's typed ``params``."""

    model_config = ConfigDict(extra="forbid")
    kind: str
    path: ModelFile
    device: Runtime[str] = "cpu"
    params: KindParams

    @abc.abstractmethod
    def build(self, *, device: str | None = None) -> Encoder:
        """The encoder (``device``, when given, overrides ``self.device``)."""

    @abc.abstractmethod
    def model_id(self) -> str:
        """The encoder's ``model_id`` computed from its files, without loading the model: the key
        calibration files and caches are tied to."""

    def describe(self) -> str:
        """Its model by file or folder name, for a log line."""
        return Path(self.path).name

    def identity(self) -> dict[str, Any]:
        """What of this section changes the embeddings (for the perception fingerprint)."""
        return {"kind": self.kind, "model_id": self.model_id(), "params": self.params.identity()}

    def resolved(self, base: Path) -> Self:
        """A copy whose ``path`` and model-file params are absolute."""
        return self.model_copy(
            update={"path": resolve_path(self.path, base), "params": self.params.resolved(base)}
        )


C = TypeVar("C", bound=BaseModel)


class Kinds(Generic[C]):
    """The registered kinds of one section (``segmenter`` or ``encoder``), by name.

    ``parse`` is the section's validator: it picks the class by ``kind`` (``default`` when the
    section names none) and validates the section against it, so a field error reads
    ``segmenter.params.scael: Extra inputs are not permitted``.
    """

    def __init__(self, section: str, base: type[C], default: str) -> None:
        self.section, self.base, self.default = section, base, default
        self._by_name: dict[str, type[C]] = {}

    def register(self, cls: type[C]) -> type[C]:
        """Class decorator: add ``cls`` under the name its ``kind`` field defaults to."""
        name = cls.model_fields["kind"].default
        if not issubclass(cls, self.base) or not isinstance(name, str):
            raise TypeError(
                f"{cls.__name__} must subclass {self.base.__name__} with kind: Literal[...] = name"
            )
        known = self._by_name.get(name)
        if known is not None and known.__qualname__ != cls.__qualname__:
            raise ValueError(f"{self.section} kind {name!r} is already registered ({known.__qualname__})")
        self._by_name[name] = cls
        return cls

    def names(self) -> list[str]:
        return sorted(self._by_name)

    def get(self, name: str) -> type[C]:
        return self._by_name[name]

    def parse(self, value: Any) -> Any:
        """A mapping -> the instance of its kind's class (other values are left to pydantic)."""
        if not isinstance(value, dict):
            return value
        name = value.get("kind", self.default)
        cls = self._by_name.get(name) if isinstance(name, str) else None
        if cls is None:
            near = difflib.get_close_matches(str(name), self.names(), n=1)
            hint = f" (did you mean {near[0]!r}?)" if near else ""
            error = PydanticCustomError(
                "unknown_kind",
                "unknown kind {kind}{hint}; known: {known}",
                {"kind": repr(name), "hint": hint, "known": ", ".join(self.names())},
            )
            raise ValidationError.from_exception_data(
                self.base.__name__, [InitErrorDetails(type=error, loc=("kind",), input=name)]
            )
        # An absent ``params`` is an empty one, so a missing required param is named as such.
        return cls.model_validate({"params": {}, **value})


# The abstract bases are passed for issubclass checks and their names, never instantiated (mypy
# refuses an abstract class for type[C]: python/mypy#4717).
SEGMENTERS: Kinds[SegmenterConfig] = Kinds("segmenter", SegmenterConfig, default="classical")  # type: ignore[type-abstract]
ENCODERS: Kinds[EncoderConfig] = Kinds("encoder", EncoderConfig, default="hf_clip")  # type: ignore[type-abstract]
