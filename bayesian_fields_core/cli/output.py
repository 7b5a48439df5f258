"""What the CLI prints while it works: the library's log lines, and third-party chatter silenced.

The library says what it is doing through the standard `logging` module, under the
``bayesian_fields_core`` logger: INFO for what a person waiting on a run wants to know ("loading
models: ...", "compiling kernels (first run only, ~10 s)"), DEBUG for the details (cache hits and
misses, model load times, per-stage timings). The CLI routes that logger to stderr through the
same rich console as the progress bars (so lines print above the bars instead of through them):

- quiet (``-q``): warnings and errors only;
- normal: INFO;
- verbose (``-v``): DEBUG.

Third-party libraries report progress their own way (transformers' "Loading weights" bar, the
Hugging Face hub's download bars, tqdm in general, ultralytics' per-image log lines). bfields says
which model it loads itself, so those are switched off, through each library's own switch
(environment variables read at import, plus the library's API when it is already imported),
unless ``-v`` asks for everything. Nothing is done by redirecting stderr.
"""

from __future__ import annotations

import logging
import os
import sys
from typing import Literal

from rich.console import Console

_CONSOLE: Console | None = None

Verbosity = Literal["quiet", "normal", "verbose"]

LIBRARY_LOGGER = "bayesian_fields_core"
_LEVELS: dict[str, int] = {"quiet": logging.WARNING, "normal": logging.INFO, "verbose": logging.DEBUG}

#: Read by the libraries when they are imported (switches for progress bars and chatter).
QUIET_ENV = {
    "HF_HUB_DISABLE_PROGRESS_BARS": "1",  # huggingface_hub, and transformers' bars follow it
    "TQDM_DISABLE": "1",  # any other tqdm bar
    "TRANSFORMERS_VERBOSITY": "error",
    "TRANSFORMERS_NO_ADVISORY_WARNINGS": "1",
    "YOLO_VERBOSE": "False",  # ultralytics
}
#: Third-party loggers held at WARNING unless verbose (PIL's DEBUG lines flood a -v run).
THIRD_PARTY_LOGGERS = (
    "transformers",
    "huggingface_hub",
    "ultralytics",
    "PIL",
    "matplotlib",
    "numba",
    "urllib3",
)


def message_console(*, stderr: bool = True) -> Console:
    """A console for messages: on a terminal, rich's own (the terminal's width); otherwise (a pipe,
    a file, a CI log) soft-wrapped, so a line is never broken at rich's default 80 columns: a
    script greps it, a log reader reflows it. Every CLI message console is made here."""
    console = Console(stderr=stderr)
    if not console.is_terminal:
        console.soft_wrap = True
    return console


def stderr_console() -> Console:
    """The one stderr console of the process: log lines and progress bars must share it."""
    global _CONSOLE
    if _CONSOLE is None:
        _CONSOLE = message_console(stderr=True)
    return _CONSOLE


class ConsoleHandler(logging.Handler):
    """Log records as plain lines on a rich console (above any live progress display)."""

    def __init__(self, console: Console) -> None:
        super().__init__()
        self.console = console

    def emit(self, record: logging.LogRecord) -> None:
        try:
            text = record.getMessage()
            if record.levelno != logging.INFO:
                text = f"{record.levelname.lower()}: {text}"
            self.console.print(text, markup=False, highlight=False, soft_wrap=True)
        except Exception:  # logging must never take the run down
            self.handleError(record)


def configure_output(console: Console, verbosity: Verbosity) -> None:
    """Route the library's logger to `console` at the level `verbosity` asks for, and switch
    third-party progress bars and chatter off unless verbose. Idempotent (one handler). The
    root logger is left alone: third-party warnings still reach stderr through Python's
    last-resort handler."""
    lib = logging.getLogger(LIBRARY_LOGGER)
    for handler in [h for h in lib.handlers if isinstance(h, ConsoleHandler)]:
        lib.removeHandler(handler)
    lib.addHandler(ConsoleHandler(console))
    lib.setLevel(_LEVELS[verbosity])
    quiet_third_party(verbosity != "verbose")


def quiet_third_party(quiet: bool) -> None:
    """Third-party progress bars and info chatter off (`quiet`) or back to their defaults."""
    for name, value in QUIET_ENV.items():
        if quiet:
            os.environ[name] = value
        elif os.environ.get(name) == value:
            del os.environ[name]
    level = logging.WARNING if quiet else logging.NOTSET
    for name in THIRD_PARTY_LOGGERS:
        logging.getLogger(name).setLevel(level)
    # Libraries imported already read their environment at import: use their own switches.
    if "transformers" in sys.modules:
        from transformers.utils import logging as hf_logging

        if quiet:
            hf_logging.set_verbosity_error()
            hf_logging.disable_progress_bar()
        else:
            hf_logging.set_verbosity_warning()
            hf_logging.enable_progress_bar()
    if "huggingface_hub" in sys.modules:
        from huggingface_hub.utils import disable_progress_bars, enable_progress_bars

        (disable_progress_bars if quiet else enable_progress_bars)()
    if "ultralytics" in sys.modules:
        from ultralytics.utils import LOGGER

        LOGGER.setLevel(logging.WARNING if quiet else logging.INFO)
