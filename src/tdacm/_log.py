"""Logging conventions shared by the library: every module logs through
``logging.getLogger(__name__)`` (all under the ``tdacm`` logger, which the command line
configures with ``-v``/``-q``); progress bars follow that logger's level."""

from __future__ import annotations

import logging

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
