"""Entry point the `bfields` CLI imports: `register_client_commands(subparsers)`."""

from .commands import register_client_commands

__all__ = ["register_client_commands"]
