"""Shared test settings."""

from __future__ import annotations

from hypothesis import settings

# No per-example deadline: the first examples pay for imports and would flake on a busy CI.
settings.register_profile("tango_aio", deadline=None)
settings.load_profile("tango_aio")
