"""The controller library a Sardana pool loads from its ``PoolPath``
(:data:`tango_aio.sardana.POOL_PATH`): the pool takes the classes defined in this file."""

from tango_aio.sardana import MarzhauserMotorController as _Controller


class MarzhauserMotorController(_Controller):
    """The axes of a Märzhäuser TANGO stage controller as pool motors (see
    :class:`tango_aio.sardana.MarzhauserMotorController`)."""
