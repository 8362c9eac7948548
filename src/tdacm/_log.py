"""Logging conventions shared by the library: every module logs through
``logging.getLogger(__name__)`` (all under the ``tdacm`` logger, which the command line
configures with ``-v``/``-q`` through :func:`configure_logging`; the benchmark scripts call it
too); progress bars follow that logger's level."""

from __future__ import annotations

import logging
import sys

#: The logger of tables that are a command's own output (``tdacm bench``): the command line
#: sends it to stdout, whatever ``-v``/``-q``; everything else goes to stderr.
REPORT = "tdacm.report"


def progress_enabled() -> bool:
    """Whether progress bars are drawn: yes while nobody configured the ``tdacm`` logger (a
    caller that asks for progress gets it), else when it shows INFO (not with ``tdacm -q``)."""
    logger = logging.getLogger("tdacm")
    if logger.level == logging.NOTSET and not logger.handlers:
        return True
    return logger.isEnabledFor(logging.INFO)


class StderrHandler(logging.StreamHandler):
    """Writes to the current ``sys.stderr`` (looked up at each record, so a replaced stderr,
    e.g. a test's capture, receives the messages)."""

    target = "stderr"

    def __init__(self):
        super().__init__(self.stream)

    @property
    def stream(self):
        return getattr(sys, self.target)

    @stream.setter
    def stream(self, value):
        pass


class StdoutHandler(StderrHandler):
    """The same on the current ``sys.stdout``: the tables of :data:`REPORT`."""

    target = "stdout"


class PlainFormatter(logging.Formatter):
    """The message alone; warnings and errors start with their level (``warning: ...``)."""

    def format(self, record: logging.LogRecord) -> str:
        text = super().format(record)
        if record.levelno >= logging.WARNING:
            text = f"{record.levelname.lower()}: {text}"
        return text


def configure_logging(verbose: int = 0, quiet: bool = False) -> None:
    """Send the ``tdacm`` loggers to stderr: INFO by default, DEBUG with ``verbose``,
    WARNING with ``quiet``; the tables of :data:`REPORT` (a command's own output)
    to stdout at any level. Replaces the handlers a previous call installed."""
    level = logging.WARNING if quiet else logging.DEBUG if verbose else logging.INFO
    report = logging.getLogger(REPORT)
    for h in [h for h in report.handlers if isinstance(h, StdoutHandler)]:
        report.removeHandler(h)
    out = StdoutHandler()
    out.setFormatter(logging.Formatter("%(message)s"))
    report.addHandler(out)
    report.setLevel(logging.INFO)
    report.propagate = False
    logger = logging.getLogger("tdacm")
    for h in [h for h in logger.handlers if isinstance(h, StderrHandler)]:
        logger.removeHandler(h)
    handler = StderrHandler()
    handler.setFormatter(PlainFormatter("%(message)s"))
    logger.addHandler(handler)
    logger.setLevel(level)


class Progress:
    """A progress line on stderr (tqdm, drawn as :func:`progress_enabled` says) that ends at
    100 % when the work is complete, and whose rate and ETA leave out its first step: a first
    step compiles numba kernels on a cold cache (seconds to minutes, against milliseconds for
    the others), so an ETA extrapolated from it would be off by orders of magnitude.
    ``initial`` steps were done before (a resumed campaign)."""

    def __init__(self, total: int, desc: str, unit: str = "step", initial: int = 0):
        from tqdm import tqdm

        self.total = int(total)
        self.initial = int(initial)
        self.bar = tqdm(
            total=self.total, initial=self.initial, desc=desc, unit=unit, file=sys.stderr,
            disable=not progress_enabled(),
        )  # fmt: skip
        self._timed = False  # the clock restarted after the first step

    def to(self, done: int) -> None:
        """Set the count to ``done`` steps (of ``total``)."""
        done = min(int(done), self.total)
        bar = self.bar
        if not self._timed and done > self.initial:
            self._timed = True
            if done < self.total:  # restart the clock after the first step, counting from it
                bar.reset(total=self.total)
                bar.initial = bar.n = bar.last_print_n = done
                bar.refresh()
                return
        bar.update(done - bar.n)

    def close(self, complete: bool = False) -> None:
        """End the line; ``complete``: the work is done (the line shows 100 %)."""
        if complete:
            self.to(self.total)
        self.bar.close()
