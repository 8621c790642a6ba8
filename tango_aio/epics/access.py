"""Who may write to the IOC's PVs (pure logic, no caproto).

Channel Access has no authentication: a client reports a host name and a user name when
it connects, and the server decides per channel what that client may do (caproto calls
``ChannelData.check_access(hostname, username)``; EPICS base's access security does the
same with the same reported names). :class:`AccessPolicy` is that decision:

* ``read_only``: nobody writes; every client reads.
* ``hosts``: if given, only clients reporting one of these host names write. Whole names
  are compared, case-insensitively (a trailing dot, DNS's root, aside), and nothing else
  is trimmed: ``pc3.lab.example`` matches only a client reporting ``pc3.lab.example`` (or
  ``PC3.LAB.EXAMPLE``), not ``pc3``, ``pc3.evil.example`` nor ``'pc3.lab.example '``;
  give each form a client may report (``--allow-host pc3 --allow-host pc3.lab.example``).
  The decision is made again at every write, with the names the client reports then.
* ``users``: if given, only clients reporting one of these user names write
  (case-sensitive, as user names are on POSIX).
* With both, a client must match both. Everyone else gets read access.

The reported names are the client's own claim. This guards a stage against mistakes (a
script on the wrong PC, a colleague's screen), not against someone who forges them; for
that, keep the IOC on loopback or on an isolated network (see ``docs/howto/epics.md``).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

__all__ = ["AccessPolicy"]


def _host(name: str) -> str:
    """A host name as compared: lower case, without a trailing dot (whole names only)."""
    return name.lower().rstrip(".")


@dataclass(frozen=True, slots=True)
class AccessPolicy:
    """Whether a Channel Access client may write (see the module docstring)."""

    read_only: bool = False
    hosts: frozenset[str] = frozenset()
    users: frozenset[str] = frozenset()

    @classmethod
    def build(cls, *, read_only: bool = False, hosts: Iterable[str] = (),
              users: Iterable[str] = ()) -> AccessPolicy:
        """Build a policy from command-line values (empty names are refused)."""
        host_set, user_set = frozenset(hosts), frozenset(users)
        for name in host_set | user_set:
            if not name or name != name.strip():
                raise ValueError("--allow-host and --allow-user need a name without "
                                 f"blanks around it, got {name!r}")
        return cls(read_only, host_set, user_set)

    @property
    def restricted(self) -> bool:
        """Whether any client is refused writes."""
        return self.read_only or bool(self.hosts) or bool(self.users)

    def may_write(self, hostname: str | None, username: str | None) -> bool:
        """Whether a client reporting ``hostname`` and ``username`` may write."""
        if self.read_only:
            return False
        if self.hosts:
            allowed = {_host(host) for host in self.hosts}
            if not hostname or _host(hostname) not in allowed:
                return False
        return not self.users or (username or "") in self.users

    def describe(self) -> str:
        """One line saying who may write, for the IOC's start-up message."""
        if self.read_only:
            return "read-only: no client may write"
        if not self.restricted:
            return "every client that reaches the IOC may write"
        parts = []
        if self.hosts:
            parts.append("hosts " + ", ".join(sorted(self.hosts)))
        if self.users:
            parts.append("users " + ", ".join(sorted(self.users)))
        return "writes only from " + " and ".join(parts) + "; others read"
