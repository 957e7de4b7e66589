"""Outbound requests to URLs that users give (webhooks): only to public addresses.

A URL someone registers is a request the server makes on their behalf from inside its network: without
a check it reaches the loopback, the private networks, the cloud metadata service (169.254.169.254) and
whatever listens there, and the delivery log becomes a port and status scanner. The rules:

- http or https only; no credentials in the URL; a port in 1-65535 (or none);
- the host is a DNS name or an IP literal in canonical form: numeric spellings that resolvers accept but
  that hide what they are (2130706433, 0x7f.0.0.1, 0177.0.0.1, 127.1) are refused outright, as are the
  loopback and metadata host names;
- the name is resolved (getaddrinfo) and EVERY address it resolves to must be public: not loopback,
  private, shared (CGNAT), link-local, multicast, reserved, unspecified or documentation, IPv4 or IPv6,
  including IPv4 addresses embedded in IPv6 ones (IPv4-mapped, 6to4, NAT64, Teredo);
- unless the operator lists the network in ``webhook_allowed_networks`` (on-premise GIS servers);
- at delivery the check runs again and the connection goes to the address that was checked (the URL's
  name travels in the Host header and the TLS SNI, and the certificate is verified against the name):
  a DNS answer that changes between the check and the connection (DNS rebinding) cannot redirect it;
  redirects are not followed and the response body is never read.

Messages of ``TargetRefused`` are safe to show to the caller: they never include resolved addresses."""

from __future__ import annotations

import ipaddress
import re
import socket
from dataclasses import dataclass
from typing import Iterable
from urllib.parse import urlsplit

IPAddress = ipaddress.IPv4Address | ipaddress.IPv6Address
IPNetwork = ipaddress.IPv4Network | ipaddress.IPv6Network

# host names that name the machine itself or a cloud metadata service, whatever they resolve to
BLOCKED_NAMES = frozenset({
    "localhost", "localhost.localdomain", "ip6-localhost", "ip6-loopback", "localhost6",
    "localhost6.localdomain6", "metadata", "metadata.google.internal", "metadata.goog", "instance-data",
    "instance-data.ec2.internal", "metadata.azure.internal", "metadata.packet.net", "kubernetes.default",
    "kubernetes.default.svc",
})
BLOCKED_SUFFIXES = (".localhost",)
NAT64_NETWORKS = (ipaddress.ip_network("64:ff9b::/96"), ipaddress.ip_network("64:ff9b:1::/48"))
_LABEL = re.compile(r"^(?!-)[a-z0-9_-]{1,63}(?<!-)$")
_NUMERIC_LABEL = re.compile(r"^(0x[0-9a-f]*|[0-9]+)$")


class TargetRefused(ValueError):
    """The URL is not an allowed outbound target; the message can be shown to the user."""


class TargetUnresolved(TargetRefused):
    """The host name does not resolve (now): at delivery, possibly a passing DNS failure."""


@dataclass(frozen=True)
class Target:
    scheme: str
    host: str                      # lower-case ASCII name, or the canonical IP literal (no brackets)
    port: int
    path: str                      # path and query, at least "/"
    addresses: tuple[str, ...]     # the checked addresses, in resolver order
    is_ip_literal: bool

    @property
    def host_header(self) -> str:
        h = f"[{self.host}]" if ":" in self.host else self.host
        default = 443 if self.scheme == "https" else 80
        return h if self.port == default else f"{h}:{self.port}"

    def pinned_url(self, address: str) -> str:
        a = f"[{address}]" if ":" in address else address
        return f"{self.scheme}://{a}:{self.port}{self.path}"


def parse_networks(values: Iterable) -> list[IPNetwork]:
    out = []
    for v in values:
        out.append(v if isinstance(v, (ipaddress.IPv4Network, ipaddress.IPv6Network))
                   else ipaddress.ip_network(str(v).strip(), strict=True))
    return out


def non_public_reason(ip: IPAddress) -> str | None:
    """Why `ip` is not a public unicast address (None when it is one)."""
    if isinstance(ip, ipaddress.IPv6Address):
        if ip.ipv4_mapped is not None:
            return non_public_reason(ip.ipv4_mapped)
        if ip.sixtofour is not None:
            inner = non_public_reason(ip.sixtofour)
            if inner:
                return inner
        if ip.teredo is not None:
            return "a Teredo tunnel address"
        if any(ip in n for n in NAT64_NETWORKS):
            return "a NAT64 address"
        if ip.is_site_local:
            return "a site-local address"
    if ip.is_unspecified:
        return "the unspecified address"
    if ip.is_loopback:
        return "a loopback address"
    if ip.is_link_local:
        return "a link-local address"
    if ip.is_multicast:
        return "a multicast address"
    if ip.is_private:
        return "a private address"
    if ip.is_reserved:
        return "a reserved address"
    if not ip.is_global:
        return "not a publicly routable address"
    if isinstance(ip, ipaddress.IPv4Address) and ip == ipaddress.IPv4Address("255.255.255.255"):
        return "the broadcast address"
    return None


def _allowed(ip: IPAddress, allowed: list[IPNetwork]) -> bool:
    if not allowed:
        return False
    candidates = [ip]
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        candidates.append(ip.ipv4_mapped)
    return any(c.version == n.version and c in n for c in candidates for n in allowed)


def _canonical_host(raw_host: str, bracketed: bool) -> tuple[str, IPAddress | None]:
    """(host, ip) where ip is set for IP literals; refuses non-canonical numeric spellings and bad names."""
    if bracketed:
        if "%" in raw_host:
            raise TargetRefused("url: IPv6 zone identifiers are not allowed")
        try:
            ip = ipaddress.IPv6Address(raw_host)
        except ValueError:
            raise TargetRefused("url: not a valid IPv6 address in brackets") from None
        return str(ip), ip
    host = raw_host
    if host.endswith("."):
        host = host[:-1]
    if not host:
        raise TargetRefused("url: a host is required")
    try:
        host = host.encode("idna").decode("ascii").lower() if not host.isascii() else host.lower()
    except UnicodeError:
        raise TargetRefused("url: the host name is not a valid internationalised name") from None
    labels = host.split(".")
    # what resolvers and browsers read as an IPv4 address (a last label that is a number, in decimal, octal
    # or hex): only the canonical dotted quad is accepted, so that what is checked is what is reached
    if _NUMERIC_LABEL.match(labels[-1]):
        try:
            ip4 = ipaddress.IPv4Address(host)
        except ValueError:
            ip4 = None
        if ip4 is None or str(ip4) != host:
            raise TargetRefused("url: numeric hosts must be written as a plain dotted IPv4 address "
                                "(a.b.c.d, no leading zeros, hex, octal or integer forms)")
        return host, ip4
    if len(host) > 253 or not all(_LABEL.match(label) for label in labels):
        raise TargetRefused("url: the host is not a valid DNS name")
    if host in BLOCKED_NAMES or host.endswith(BLOCKED_SUFFIXES):
        raise TargetRefused("url: this host name designates the server itself or a metadata service")
    return host, None


def parse_url(url: str) -> tuple[str, str, int, str, IPAddress | None]:
    """(scheme, host, port, path, ip literal or None) of an outbound URL; TargetRefused when unusable."""
    if not isinstance(url, str) or not url or len(url) > 2000:
        raise TargetRefused("url: an http(s) URL of at most 2000 characters expected")
    if any(ord(c) <= 0x20 or ord(c) == 0x7F for c in url) or "\\" in url:
        raise TargetRefused("url: spaces, control characters and backslashes are not allowed")
    try:
        u = urlsplit(url)
    except ValueError:
        raise TargetRefused("url: not a valid URL") from None
    scheme = u.scheme.lower()
    if scheme not in ("http", "https"):
        raise TargetRefused("url: only http and https URLs are allowed")
    if not u.netloc:
        raise TargetRefused("url: a host is required")
    if "@" in u.netloc:
        raise TargetRefused("url: credentials in the URL are not allowed (the receiver authenticates "
                            "deliveries with the HMAC signature)")
    try:
        port = u.port
    except ValueError:
        raise TargetRefused("url: the port must be a number from 1 to 65535") from None
    if port is not None and not 1 <= port <= 65535:
        raise TargetRefused("url: the port must be a number from 1 to 65535")
    hostport = u.netloc
    bracketed = hostport.startswith("[")
    raw_host = u.hostname or ""
    if not raw_host:
        raise TargetRefused("url: a host is required")
    host, ip = _canonical_host(raw_host, bracketed)
    path = u.path or "/"
    if u.query:
        path += "?" + u.query
    return scheme, host, port or (443 if scheme == "https" else 80), path, ip


def resolve(host: str, port: int) -> list[str]:
    """Every address the system resolver gives for host (socket.getaddrinfo; tests replace it)."""
    infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    out: list[str] = []
    for family, _, _, _, sockaddr in infos:
        if family not in (socket.AF_INET, socket.AF_INET6):
            continue
        a = str(sockaddr[0]).split("%", 1)[0]
        if a not in out:
            out.append(a)
    return out


def check_url(url: str, allowed_networks: Iterable = ()) -> Target:
    """Parse, resolve and check an outbound URL. TargetRefused (message safe to show) when it is not
    allowed; OSError subclasses (socket.gaierror) are turned into TargetRefused too."""
    scheme, host, port, path, ip = parse_url(url)
    allowed = parse_networks(allowed_networks)
    if ip is not None:
        if not _allowed(ip, allowed):
            why = non_public_reason(ip)
            if why:
                raise TargetRefused(f"url: {ip} is {why}; webhooks may only call public addresses")
        return Target(scheme, host, port, path, (str(ip),), True)
    try:
        addresses = resolve(host, port)
    except (OSError, UnicodeError):
        raise TargetUnresolved("url: the host name does not resolve") from None
    if not addresses:
        raise TargetUnresolved("url: the host name does not resolve")
    for a in addresses:
        try:
            addr = ipaddress.ip_address(a)
        except ValueError:
            raise TargetRefused("url: the host name resolves to something that is not an IP address") from None
        if _allowed(addr, allowed):
            continue
        why = non_public_reason(addr)
        if why:
            # the address itself is not echoed: the answer would map internal DNS for the caller
            raise TargetRefused(f"url: the host name resolves to {why}; webhooks may only call public "
                                "addresses")
    return Target(scheme, host, port, path, tuple(addresses), False)


def post_pinned(target: Target, body: bytes, headers: dict, timeout_s: float) -> int:
    """POST body to the target, connecting to the first checked address (no new resolution), with the
    URL's host in Host and TLS SNI (certificate verified against it). Returns the status code; the
    response body is not read; redirects are not followed. Raises httpx.HTTPError on network errors."""
    import httpx

    address = target.addresses[0]
    extensions = {}
    if target.scheme == "https" and not target.is_ip_literal:
        extensions["sni_hostname"] = target.host
    h = {**headers, "Host": target.host_header}
    # trust_env=False: no HTTP(S)_PROXY from the environment (a proxy would resolve the name again)
    with httpx.Client(timeout=timeout_s, follow_redirects=False, trust_env=False) as client:
        req = client.build_request("POST", target.pinned_url(address), content=body, headers=h,
                                   extensions=extensions)
        r = client.send(req, stream=True)
        try:
            return r.status_code
        finally:
            r.close()
