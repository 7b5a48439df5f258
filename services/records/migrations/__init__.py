"""Alembic migrations of the records schema (`env.py`, `versions/`); run through `database.migrate`."""
