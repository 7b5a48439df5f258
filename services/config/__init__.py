"""The service's configuration: one pydantic-settings object (`settings.ServiceSettings`) read
from the ``BFIELDS_*`` environment variables, documented in `.env.example`.

Why a package at the bottom: every other package reads settings, so settings import nothing of
the service and no service module reads the environment itself.
"""
