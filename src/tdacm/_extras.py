"""Optional dependencies: the modules that only one application needs (campaigns, the
Gymnasium env, Rerun recordings, the live server) are installed with an extra of the package,
and importing them through :func:`require` turns a missing module into an error that names the
extra."""

from __future__ import annotations

import importlib
from types import ModuleType

#: extra -> what it enables (the subject of the error message)
EXTRAS = {
    "campaign": "tdacm campaigns",
    "env": "the tdacm Gymnasium env",
    "rerun": "tdacm Rerun recordings",
    "recording": "tdacm MCAP recordings",
    "live": "tdacm live views (Foxglove)",
}


class MissingExtraError(ImportError):
    """An optional dependency is not installed; the message names the extra to install."""


def require(module: str, extra: str) -> ModuleType:
    """``import module``; if it is missing, raise :class:`MissingExtraError` naming the extra to install,
    e.g. ``tdacm campaigns need the 'campaign' extra: pip install 'tdacm[campaign]'``."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise MissingExtraError(
            f"{EXTRAS[extra]} need the '{extra}' extra: pip install 'tdacm[{extra}]' "
            f"(missing module: {exc.name or module})"
        ) from exc
