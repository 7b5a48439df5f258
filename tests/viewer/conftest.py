from tests.ui.browser import browser  # noqa: F401 - fixture found by name
