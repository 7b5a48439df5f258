"""A throwaway ASGI app with /healthz, to prove the api_server fixture without the real API."""

from __future__ import annotations

import os

from fastapi import FastAPI

app = FastAPI()


@app.get("/healthz")
def healthz() -> dict[str, str]:
    return {
        "status": "ok",
        "redis": os.environ.get("BFIELDS_REDIS_URL", ""),
        "home": os.environ.get("HOME", ""),
    }
