"""bluesky."""

from __future__ import annotations

from ._devices import (
    MarzhauserAxis,
    MarzhauserFlyer,
    MarzhauserStage,
    MissingAxisError,
    StageLimitsError,
    StageLink,
    TriggerScan,
    close_stage,
    controller_velocity,
    egu_acceleration,
    egu_velocity,
    fly_raster,
    home,
    max_velocity,
    measure_range,
    run_up_distance,
)

__all__ = [
    "MarzhauserAxis",
    "MarzhauserFlyer",
    "MarzhauserStage",
    "MissingAxisError",
    "StageLimitsError",
    "StageLink",
    "TriggerScan",
    "close_stage",
    "controller_velocity",
    "egu_acceleration",
    "egu_velocity",
    "fly_raster",
    "home",
    "max_velocity",
    "measure_range",
    "run_up_distance",
]
