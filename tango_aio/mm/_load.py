"""``load_tango``: a TANGO's devices loaded into a UniMMCore in one call."""

from __future__ import annotations

from typing import Any

from pymmcore_plus.experimental.unicore import Device, UniMMCore

from ._hub import TangoHub
from ._shutter import TangoShutter, TangoStrobe
from ._stages import TangoXYStage, TangoZStage


def load_tango(core: UniMMCore, url: str, *, xy: str | None = "xy", z: str | None = "z",
               shutter: bool = True, strobe: bool = False, prefix: str = "Tango",
               **options: Any) -> dict[str, str]:
    """Connect to the TANGO at ``url`` and load its devices into ``core``: the hub, an
    XY stage on the axes ``xy``, a focus stage on the axis ``z``, the AUX shutter and
    (if asked) the LED strobe; each initialised, made the core's XY stage, focus device
    and shutter (the AUX shutter, or the strobe without it), and labelled ``prefix`` +
    ``Hub``, ``XY``, ``Z``, ``Shutter``, ``Strobe``.

    Parameters
    ----------
    core
        The core to load them into.
    url
        Where the controller is (``"/dev/ttyUSB0"``, ``"COM3"``, ``"sim://"``...).
    xy
        The two axes of the XY stage (``"xy"``); ``None`` or ``""``: no XY stage.
    z
        The axis of the focus stage (``"z"``, or any axis); ``None`` or ``""``: none.
    shutter
        Whether to load the shutter.
    strobe
        Whether to load the LED strobe on TAKT_OUT (:class:`TangoStrobe`; not in the
        older edition).
    prefix
        The start of every label.
    **options
        Further options of :func:`tango_aio.connect`.

    Returns
    -------
    dict[str, str]
        The label of each loaded device by role (``hub``, ``xy``, ``z``, ``shutter``,
        ``strobe``).

    Raises
    ------
    ValueError
        ``xy`` is not two axes, or an axis the controller lacks (nothing stays loaded).
    ConnectError
        The controller cannot be reached (nothing is loaded).
    """
    if xy and len(xy) != 2:
        raise ValueError(f"xy names two axes (e.g. 'xy'), got {xy!r}")
    hub = TangoHub(url, **options)
    hub.controller  # noqa: B018 - connects here, so that a failure raises here
    devices: dict[str, Device] = {"hub": hub}
    if xy:
        devices["xy"] = TangoXYStage(hub, x=xy[0], y=xy[1])
    if z:
        devices["z"] = TangoZStage(hub, axis=z)
    if shutter:
        devices["shutter"] = TangoShutter(hub)
    if strobe:
        devices["strobe"] = TangoStrobe(hub)
    names = {"hub": "Hub", "xy": "XY", "z": "Z", "shutter": "Shutter", "strobe": "Strobe"}
    labels = {role: prefix + names[role] for role in devices}
    loaded: list[str] = []
    try:
        for role, device in devices.items():
            core.loadPyDevice(labels[role], device)
            loaded.append(labels[role])
            if role != "hub":
                core.setParentLabel(labels[role], labels["hub"])
            device.initialize()  # raises here, where the core would only log it
            core.initializeDevice(labels[role])
    except BaseException:
        for label in reversed(loaded):
            core.unloadDevice(label)
        hub.shutdown()
        raise
    if "xy" in labels:
        core.setXYStageDevice(labels["xy"])
    if "z" in labels:
        core.setFocusDevice(labels["z"])
    if "shutter" in labels or "strobe" in labels:
        core.setShutterDevice(labels.get("shutter", labels.get("strobe", "")))
    return labels
