"""TANGO stages as ophyd-async devices for Bluesky (``pip install 'tango-aio[bluesky]'``).

Tested with ophyd-async 0.21 and bluesky 1.15 (the extra pins ophyd-async to 0.21.x,
because its motor API changes between releases)::

    from bluesky import RunEngine
    import bluesky.plans as bp
    from ophyd_async.core import init_devices
    from tango_aio.bluesky import MarzhauserStage

    RE = RunEngine()
    with init_devices():                    # connects on the RunEngine's event loop
        stage = MarzhauserStage("sim://?baud=0", axes="xy")
    RE(bp.grid_scan([stage], stage.y, 0, 1, 3, stage.x, 0, 2, 5))

Devices:

* :class:`MarzhauserStage` - one controller; a child :class:`MarzhauserAxis` per axis
  letter (``stage.x``, ``stage.y``...). ``connect()`` opens the driver (on the event loop
  it runs on, which :func:`ophyd_async.core.init_devices` makes the RunEngine's) and
  checks that the controller has the axes.
* :class:`MarzhauserAxis` - a drop-in for ophyd-async's ``epics.motor.Motor`` where the
  controller can back it (Movable, Locatable, Stoppable, Readable, Configurable,
  Preparable, Flyable): ``user_readback`` (hinted; named like the axis, e.g.
  ``stage-x``) and ``user_setpoint`` in the axis's ``dim`` unit (EGU) with the precision
  of the controller's ``?pos`` replies; ``velocity`` in EGU/s, ``max_velocity``,
  ``acceleration_time``, ``motor_egu``, ``motor_done_move``, ``offset``, travel and
  dial limits, limit switches and the rest of the table in ``docs/howto/bluesky.md``.
  ``set()`` checks the limits (``?lim``, read again only after a line that may change
  them: :meth:`~tango_aio.Controller.axis_limits`), reports progress
  (:class:`~ophyd_async.core.WatcherUpdate` from positions polled while the move runs)
  and publishes the confirmed final readback before it completes.
  ``prepare(FlyMotorInfo(...))``/``kickoff()``/``complete()`` fly it as Motor does;
  ``home()``, ``measure_range()``, ``set_current_position()`` and ``clear_offset()``
  return statuses (plan stubs :func:`home`, :func:`measure_range`).
* :class:`MarzhauserFlyer` - a hardware-triggered fly scan of one axis with the trigger
  output (and, optionally, snapshot capture); :func:`fly_raster` runs a raster of them.
  Its documents carry the trigger positions of each pass (stream ``<name>_triggers``).

Behaviour that follows from the controller:

* Moves on one controller run one after another. Sets of different axes that arrive
  together (``bps.mv(stage.x, 1, stage.y, 2)``) are merged by
  :class:`~tango_aio.group._coalesce.MoveCoalescer` into one ``!moa`` line.
* ``stop()`` of an axis stops that axis alone (the manual's ``a x``, L6785-6844), and
  only if it moves: a move of another axis goes on. ``stop(success=False)`` makes the
  stopped axis's ``set()`` status fail; ``success=True`` (RunEngine pause) completes it.
  A line that merged the stopped axis with others fails in the driver as a whole; the
  sets of its other axes still complete if those axes are confirmed idle at their
  targets afterwards (fresh ``?statusaxis`` and ``?pos``), else they fail.
* While idle, nothing is polled: readbacks follow the driver's events (a move of any
  caller of the same controller ends: one ``?pos``).
* Devices share a plain :class:`StageLink` (URL, open controller, coalescer); an axis
  never keeps its parent device as an attribute, because ophyd-async would adopt it as a
  child.
* Numbers from plans are numpy scalars; they are converted with ``float()`` here.
* ``init_devices(mock=True)`` connects the stage without a controller: the axes move
  instantly (ophyd-async's mock behaviour), for testing plans. The flyer needs a
  controller.
"""

from __future__ import annotations

from ..errors import MissingAxisError, StageLimitsError
from ._axis import MarzhauserAxis
from ._flyer import MarzhauserFlyer, TriggerScan, fly_raster
from ._link import StageLink
from ._speeds import (
    controller_velocity,
    egu_acceleration,
    egu_velocity,
    max_velocity,
    run_up_distance,
)
from ._stage import MarzhauserStage, close_stage, home, measure_range

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
