"""Write the fingerprints of the emulator's own profiles to ``examples/fingerprints/``.

``python tools/gen_fingerprints.py`` probes ``sim://`` under each profile of
:data:`tango_aio.sim.profiles.PROFILES` (with moves and ``!save``, as a lab would run
``tango-aio probe URL --moves --save``) and writes ``<profile>.json``. The files are the
examples of the docs page "Help us support your controller"; ``tests/e2e/test_firmware_probe.py``
checks that they are current (:func:`tango_aio.fieldkit.comparable`).
"""

from __future__ import annotations

import asyncio
import urllib.parse
from pathlib import Path

from tango_aio.fieldkit._probe import ProbeOptions, ProbeResult, probe, write_fingerprint
from tango_aio.sim.profiles import PROFILES

#: Where the example fingerprints live.
EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "fingerprints"

#: The probe's options for the examples: everything it can observe, quickly.
OPTIONS = ProbeOptions(moves=True, save=True, settle=0.05, move_time=0.05)


def example_url(profile: str) -> str:
    """The emulator an example fingerprint is taken from."""
    return "sim://?" + urllib.parse.urlencode({"baud": 0, "speed": 10, "profile": profile})


async def probe_profiles() -> dict[str, ProbeResult]:
    """A probe of every profile."""
    names = list(PROFILES)
    results = await asyncio.gather(*(probe(example_url(name), OPTIONS) for name in names))
    return dict(zip(names, results, strict=True))


def main() -> None:
    """Write every profile's fingerprint."""
    EXAMPLES.mkdir(parents=True, exist_ok=True)
    for name, result in asyncio.run(probe_profiles()).items():
        print(write_fingerprint(result, EXAMPLES / f"{name}.json"))


if __name__ == "__main__":
    main()
