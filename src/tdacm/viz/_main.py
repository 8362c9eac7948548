"""``python -m tdacm.viz.<module> [PATH]``: draw one of the documentation's model figures."""

from __future__ import annotations

import sys


def figure_main(draw, default_path: str, argv=None) -> int:
    """Call ``draw(path)`` with the first argument of ``argv`` (default ``sys.argv[1:]``) or
    ``default_path``; the exit status is 0."""
    argv = sys.argv[1:] if argv is None else argv
    draw(argv[0] if argv else default_path)
    return 0
