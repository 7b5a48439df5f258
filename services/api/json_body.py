"""JSON bodies a route parses itself, in a worker thread instead of on the event loop.

FastAPI parses and validates a declared body model inside the event loop. For a fleet-sized body
(a 5,000-item batch) that is over a hundred milliseconds of the loop under load during which the
process answers no other request, so one tenant's batch stalls every other tenant's calls on the
same API process (measured by `bench/bench_batch_ops.py --other-tenant`). A route that takes the
raw `Request` instead reads the bytes on the loop (cheap), and parses, validates and answers in a
worker thread, where the loop keeps interleaving other requests. Two things FastAPI did for the
declared model are kept here: the body's schema in the OpenAPI document (`openapi_body` names it,
`add_body_schemas` puts the model and what it nests into the components), and a validation
failure answered as FastAPI's own 422 (`parse_body` raises `RequestValidationError` with the
error locations under "body").
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar

from fastapi import FastAPI
from fastapi.exceptions import RequestValidationError
from pydantic import BaseModel, ValidationError

Model = TypeVar("Model", bound=BaseModel)

_COMPONENTS = "#/components/schemas/{model}"


def openapi_body(model: type[BaseModel]) -> dict[str, Any]:
    """The route's `openapi_extra`: a required JSON body of `model`'s schema."""
    ref = {"$ref": _COMPONENTS.format(model=model.__name__)}
    return {"requestBody": {"required": True, "content": {"application/json": {"schema": ref}}}}


def parse_body(model: type[Model], raw: bytes) -> Model:
    """`raw` as `model`, or FastAPI's 422 for a body that is not JSON or not that model."""
    try:
        return model.model_validate_json(raw or b"null")
    except ValidationError as exc:
        errors = exc.errors(include_url=False)
        raise RequestValidationError(
            [{**e, "loc": ("body", *e.get("loc", ()))} for e in errors], body=raw
        ) from None


def add_body_schemas(app: FastAPI, models: list[type[BaseModel]]) -> None:
    """Add `models` (and the models they nest) to the app's OpenAPI components, where the routes'
    `openapi_body` references point."""
    build: Callable[[], dict[str, Any]] = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is not None:
            return app.openapi_schema
        document = build()
        schemas = document.setdefault("components", {}).setdefault("schemas", {})
        for model in models:
            schema = model.model_json_schema(ref_template=_COMPONENTS)
            for name, nested in schema.pop("$defs", {}).items():
                schemas.setdefault(name, nested)
            schemas[model.__name__] = schema
        app.openapi_schema = document
        return document

    app.openapi = openapi  # type: ignore[method-assign]  # FastAPI's documented way to extend it
