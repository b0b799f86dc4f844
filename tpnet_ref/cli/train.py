"""Temporary shim: registers the ``tpnet`` sub-commands still defined in tpnet_ref.train (being moved here)."""
from __future__ import annotations

from typing import Any


def add_cli(sub: Any) -> None:
    from ..train import add_cli as _add
    _add(sub)
