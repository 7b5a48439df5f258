"""HTTP client of the batch service and the `bfields submit|status|fetch|batch` commands."""

from bayesian_fields_service.client.api import BFieldsClient, ClientError
from bayesian_fields_service.client.commands import batch, fetch, register_client_commands, status, submit

__all__ = ["BFieldsClient", "ClientError", "batch", "fetch", "register_client_commands", "status", "submit"]
