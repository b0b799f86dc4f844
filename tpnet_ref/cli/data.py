"""Temporary shim: registers the ``tpnet`` sub-commands still defined in tpnet_ref.data (being moved here)."""
from __future__ import annotations

from typing import Any


def add_cli(sub: Any) -> None:
    from ..data import add_cli as _add
    _add(sub)
