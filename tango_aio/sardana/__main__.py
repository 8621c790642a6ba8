"""``python -m tango_aio.sardana``: print the folder to add to a pool's ``PoolPath``."""

from tango_aio.sardana import POOL_PATH

if __name__ == "__main__":
    print(POOL_PATH)
