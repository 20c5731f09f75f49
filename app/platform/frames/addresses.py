"""Which network addresses a camera source may reach.

A source URL is the admin's, but the service fetches it from inside its own network: a URL
naming the machine itself (loopback), a cloud's metadata service (link-local 169.254.169.254)
or an address no camera can have would turn the puller into a way to reach what is not a
camera. Every address a source's host resolves to is checked, at registration and again at
each connection (a name may resolve elsewhere later). Refused: loopback, link-local,
unspecified (and IPv4's "this network" 0.0.0.0/8), multicast and reserved ranges; an
IPv6-mapped IPv4 address is judged as the IPv4 one. Private LANs and public addresses are
allowed, since cameras live there. Networks the operator lists
(``VANTAGE_SOURCE_ALLOWED_NETWORKS``) are allowed whatever the rule says.
"""

from __future__ import annotations

import ipaddress
import socket
from collections.abc import Sequence
from urllib.parse import urlsplit

IPAddress = ipaddress.IPv4Address | ipaddress.IPv6Address
IPNetwork = ipaddress.IPv4Network | ipaddress.IPv6Network

THIS_NETWORK = ipaddress.ip_network("0.0.0.0/8")
"""RFC 791's "this host on this network": Linux connects 0.x.y.z to the machine itself."""


class AddressRefused(ValueError):
    """A source's host resolves to an address the rule refuses, or does not resolve."""


def networks(cidrs: Sequence[str]) -> tuple[IPNetwork, ...]:
    """The operator's allowed networks, parsed (settings checked their form)."""
    return tuple(ipaddress.ip_network(c, strict=False) for c in cidrs)


def rule_refusing(address: IPAddress) -> str | None:
    """The rule that refuses ``address`` ("loopback", "link-local", …), or None."""
    if isinstance(address, ipaddress.IPv6Address) and address.ipv4_mapped is not None:
        address = address.ipv4_mapped
    if address.is_loopback:
        return "loopback"
    if address.is_link_local:
        return "link-local"
    if address.is_unspecified or address in THIS_NETWORK:
        return "unspecified"
    if address.is_multicast:
        return "multicast"
    if address.is_reserved:
        return "reserved"
    return None


def check(address: IPAddress, allowed: Sequence[IPNetwork]) -> None:
    """Raise AddressRefused naming the rule, unless ``address`` is allowed."""
    rule = rule_refusing(address)
    if rule is None or any(address in n for n in allowed if n.version == address.version):
        return
    raise AddressRefused(
        f"the source's host resolves to a {rule} address ({address}), which sources may not "
        "reach; an operator may allow the network with VANTAGE_SOURCE_ALLOWED_NETWORKS"
    )


DEFAULT_PORTS = {"http": 80, "https": 443, "rtsp": 554}


def resolve_url(url: str, allowed: Sequence[IPNetwork]) -> list[IPAddress]:
    """``resolve`` of a source URL's host, on its port (the scheme's when it names none)."""
    parts = urlsplit(url)
    port = parts.port or DEFAULT_PORTS.get(parts.scheme.lower(), 80)
    return resolve(parts.hostname or "", port, allowed)


def resolve(host: str, port: int, allowed: Sequence[IPNetwork]) -> list[IPAddress]:
    """Every address ``host`` resolves to, each checked; AddressRefused when one is refused
    (a name with one bad address among good ones is refused: which one a client takes is not
    ours to choose) or when the name does not resolve. Blocking (DNS): call from a thread."""
    try:
        literal = ipaddress.ip_address(host.strip("[]"))
    except ValueError:
        literal = None
    if literal is not None:
        check(literal, allowed)
        return [literal]
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except (OSError, UnicodeError):
        raise AddressRefused(f"the source's host {host!r} does not resolve") from None
    found: list[IPAddress] = []
    for *_, sockaddr in infos:
        address = ipaddress.ip_address(str(sockaddr[0]).split("%")[0])
        check(address, allowed)
        if address not in found:
            found.append(address)
    if not found:
        raise AddressRefused(f"the source's host {host!r} does not resolve")
    return found
