"""The Channel Access IOC: TANGO axes as motor records, served by caproto.

For each controller (prefix ``P:``, or ``P:name:`` with several controllers):

* ``P:X`` ... ``P:A``: a motor record per present axis (see :mod:`.record` for units).
  A put to VAL starts the move (through a :class:`~tango_aio.group._coalesce.MoveCoalescer`,
  so puts to different axes that arrive together become one ``!moa`` line); a put with
  callback completes when the move has ended and the final RBV, MOVN=0 and DMOV=1 are on
  the wire to every client (:mod:`.flush`). A move that ends anywhere but at its target
  (any status letter but @/A/D, a controller error, a lost link, a refused line) fails
  the put, sets the MSTA problem bit and puts the record and its fields in a MAJOR alarm
  until a move ends at its target (one rule for every PV of the axis,
  :func:`~.record.fault_after`: STOP and SPMG neither raise nor clear it); VAL and DVAL
  are then where the axis stands, as after STOP or SPMG=Stop (the motor record's rule;
  SPMG=Pause keeps them, Go resumes toward VAL).
* ``P:CONNECTED`` (0/1), ``P:ERROR`` (number of the last error: the controller's error
  number, -1 for a failure without one, 0 none), ``P:ERROR:TEXT``, ``P:AUTOSTATUS``,
  ``P:TRIGCOUNT``.

One poller per controller reads ``?pos`` and ``?statusaxis`` every ``poll`` seconds and
``?readsw``, ``?statuslimit`` and ``?trigcount`` every fifth time. While the link is down
every PV but CONNECTED is in an INVALID/COMM alarm; when the driver has reconnected
(``connect(url, reconnect=True)``) the settings are read again and the alarms go back to
the axis's own (a move that failed with the link still shows its fault). Every fifth poll
also publishes the soft limits the driver knows (read again after any line that may
change them), and every 25th reads the unit settings (``dim``, ``pitch``, ``gear``,
``usteps``, ``resolution``), so the limits, EGU, PREC, MRES, UREV, SREV, RDBD and the
speeds follow a change made through any path. The fields the motor record derives
(RVAL, RRBV, DIFF, the last values, S/SMAX, TDIR, MIP: :func:`~.record.derived_fields`)
are published with the values they derive from.

Choices (the motor record documentation leaves room, the TANGO has no such concepts):

* Motion requests run one at a time per axis (:class:`~.axis.AxisServer`): a VAL put during a
  move retargets (the one-axis stop ``a x``, L6785-6844, then the new move), and a newer
  request replaces a waiting one. STOP, and SPMG set to Stop or Pause, stop the axis the
  same way and drop every waiting request; the stopped put fails (the target was not
  reached), its alarm left as it was. While SPMG is Stop or Pause every motion request is refused
  (the flag is set before the stop is awaited, so a VAL right behind it is refused too);
  Pause then Go resumes the move toward VAL.
* HOMR runs ``cal`` (reverse, to the lower limit switch, sets the origin, L5259), HOMF
  runs ``rm`` (forward, to the upper limit switch, sets the upper limit, L5343).
* SET=Set: a put to VAL redefines the position instead of moving; with FOFF=Variable the
  user offset OFF changes, with FOFF=Frozen the controller's position is set (``!pos``,
  L6900).
* HLM/LLM and DHLM/DLLM are the controller's soft limits (``!lim``, L4522), served as
  VAL's (user) and DVAL's, DRVH's and DRVL's (dial) control limits, which clients check
  before they put; a target outside them sets LVIO=1, keeps VAL, blinks DMOV (0, then 1)
  and fails the put, with the axis in a HIGH or LOW/MAJOR alarm, before anything is sent
  (the motor record's rule, limits 0 and 0 meaning none).
* VELO sets ``vel`` (at most VMAX, which starts at the controller's own speed); ACCL sets
  ``accel`` so that VELO is reached in ACCL seconds; a new VELO keeps ``accel`` (ACCL is
  recomputed: ACCU is Accs, ACCS the acceleration in EGU/s²). DVAL and RLV move through
  VAL, SSET/SUSE switch SET; DIR (but Pos), VBAS (but 0), JOGF/JOGR/JVEL, RVAL and MRES
  refuse writes (:data:`~.fields.REFUSED`), and every field not in
  :data:`~.fields.WRITABLE` is read-only.
* CNEN Enable/Disable sends ``!axis <axis> 1`` / ``0`` (L3919: a disabled axis keeps its
  motor current, so a vertical axis does not drop; ``-1``, power off, is never sent). A
  moving axis is stopped first, as by STOP: the manual does not say what disabling does
  to a move (L3919-3960).

The parts: :mod:`.fields` the record's fields and put handlers, :mod:`.axis` one axis
behind its record (motions, put completion, alarms), :mod:`.server` the controllers'
servers, their pollers and the IOC.
"""

from __future__ import annotations

from ..errors import MotorRefusedError, MoveStoppedError
from .server import TangoIoc, build_ioc

__all__ = ["MotorRefusedError", "MoveStoppedError", "TangoIoc", "build_ioc"]
