"""The trigger/gate controller library a Sardana pool loads from its ``PoolPath``
(:data:`tango_aio.sardana.POOL_PATH`)."""

from tango_aio.sardana import MarzhauserTriggerGateController as _Controller


class MarzhauserTriggerGateController(_Controller):
    """The trigger output of a Märzhäuser TANGO stage controller as a pool trigger/gate
    (see :class:`tango_aio.sardana.MarzhauserTriggerGateController`)."""
