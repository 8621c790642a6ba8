"""Serve TANGO controllers over EPICS Channel Access as standard motor records.

``tango-aio ioc URL --prefix P:`` (install the extra ``tango-aio[epics]``, which brings
caproto) makes every present axis a motor record (``P:X``, ``P:Y`` ...) and adds
controller PVs (``P:CONNECTED``, ``P:ERROR``, ``P:AUTOSTATUS``, ``P:TRIGCOUNT``); see
``docs/howto/epics.md``.

* :mod:`tango_aio.epics.access` - who may write (pure, no caproto);
* :mod:`tango_aio.epics.record` - motor-record arithmetic: units, MSTA bits, switches
  (pure, no caproto);
* :mod:`tango_aio.epics.ioc` - the IOC (:func:`~tango_aio.epics.ioc.build_ioc`), served by
  :mod:`~tango_aio.epics.fields` (the record's fields and PV groups),
  :mod:`~tango_aio.epics.axis` (one axis behind its record) and
  :mod:`~tango_aio.epics.server` (the controllers' pollers and the IOC);
* :mod:`tango_aio.epics.command` - the ``ioc`` subcommand of ``tango-aio``.

Only :mod:`~tango_aio.epics.ioc` and the modules behind it (and :mod:`.flush`) import
caproto, so the command line and the pure parts work without it.
"""

from __future__ import annotations

__all__: list[str] = []
