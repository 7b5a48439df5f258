"""Defaults the client's verbs and their argument wiring share (a leaf: imports nothing)."""

DEFAULT_SERVER = "http://127.0.0.1:8000"
"""The API a client verb talks to without --server or $BFIELDS_SERVER."""
