"""The API's check of a `callback_url` (the rules are `common.callbacks.check_callback_url`)."""

from __future__ import annotations

from fastapi import HTTPException

from bayesian_fields_core.errors import InputError
from bayesian_fields_service.common.callbacks import check_callback_url
from bayesian_fields_service.common.settings import ServiceSettings


def checked_callback(settings: ServiceSettings, url: str | None) -> str | None:
    """`url` when a callback may go there (None stays None), else 422 naming the rule."""
    if url is None:
        return None
    try:
        return check_callback_url(url, settings)
    except InputError as exc:
        raise HTTPException(422, str(exc)) from None
