"""HTTPS for the robot's pages: the certificate, the plain-http redirect, the robot's addresses.

Browsers give a page the microphone only in a secure context (https, or localhost), so a
visitor's phone can hold to talk only when the robot serves HTTPS. ``web.tls``:

- ``auto`` (default): HTTPS when the server listens beyond loopback (``web.host`` 0.0.0.0 or
  a network address: phones reach it); plain http when it listens on loopback only (the
  robot's own browser, tests), where localhost is a secure context already.
- ``on`` / ``off``: always / never.

The certificate is the operator's (``web.tls_cert`` + ``web.tls_key``), or one SAGE makes on
first run: self-signed, ECDSA P-256, for the machine's hostname (and ``<hostname>.local``),
``localhost``, loopback and every non-loopback address of the machine (plus
``web.public_host``), stored in ``$SAGE_STATE_DIR/tls/`` and reused until it expires or an
address of the machine is missing from it. ``web.http_port`` then answers plain http with a
redirect to the same path and query on HTTPS.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import ipaddress
import os
import socket
import ssl
import struct
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from sage_robot.core.config.areas import WebSettings
from sage_robot.core.errors import ConfigError
from sage_robot.core.log import get_logger

CERT_DAYS = 825  # the longest validity Apple devices accept for a certificate trusted by hand
RENEW_BEFORE_DAYS = 30  # a certificate this close to its end is made anew
TLS_DIRNAME = "tls"
CERT_FILENAME = "cert.pem"
KEY_FILENAME = "key.pem"
_SIOCGIFADDR = 0x8915  # Linux ioctl: an interface's IPv4 address

_log = get_logger("web")


@dataclass(frozen=True)
class CertPair:
    cert: Path
    key: Path
    made_here: bool  # SAGE's own self-signed certificate (not the operator's)


def is_loopback(host: str) -> bool:
    """``host`` (an address or name) reaches only this machine."""
    if host.lower() in ("localhost", "localhost.localdomain") or host.lower().endswith(".localhost"):
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def tls_enabled(web: WebSettings) -> bool:
    """Whether the pages are served over HTTPS (see the module's docstring for ``auto``)."""
    if web.tls == "auto":
        return not is_loopback(web.host)
    return web.tls == "on"


def lan_addresses() -> list[str]:
    """The machine's non-loopback IPv4 addresses (the ones phones on its network can reach), best first.

    The address of the default route comes first; then every interface's (Linux); then what the
    hostname resolves to. Link-local (169.254.x.x) addresses come last.
    """
    found: list[str] = []

    def add(addr: str) -> None:
        with contextlib.suppress(ValueError):
            ip = ipaddress.ip_address(addr)
            if not ip.is_loopback and not ip.is_unspecified and addr not in found:
                found.append(addr)

    with contextlib.suppress(OSError), socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.connect(("192.0.2.1", 9))  # UDP: sends nothing, only picks the outgoing address
        add(s.getsockname()[0])
    for addr in _interface_addresses():
        add(addr)
    with contextlib.suppress(OSError):
        for info in socket.getaddrinfo(socket.gethostname(), None, socket.AF_INET):
            add(str(info[4][0]))
    return sorted(found, key=lambda a: ipaddress.ip_address(a).is_link_local)


def _interface_addresses() -> list[str]:
    if not sys.platform.startswith("linux"):
        return []
    import fcntl

    out = []
    with contextlib.suppress(OSError), socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for _, name in socket.if_nameindex():
            packed = struct.pack("256s", name.encode()[:15])
            with contextlib.suppress(OSError):
                out.append(socket.inet_ntoa(fcntl.ioctl(s.fileno(), _SIOCGIFADDR, packed)[20:24]))
    return out


def public_host(web: WebSettings) -> str:
    """The name or address phones use to reach the robot: ``web.public_host``, else its first
    non-loopback address, else ``localhost``."""
    if web.public_host:
        return web.public_host
    if not is_loopback(web.host) and web.host not in ("0.0.0.0", "::"):
        return web.host
    return next(iter(lan_addresses()), "localhost")


def url_host(host: str) -> str:
    """``host`` as it goes in a URL (IPv6 in brackets)."""
    return f"[{host}]" if ":" in host and not host.startswith("[") else host


# ---------------------------------------------------------------- the certificate
def tls_dir(state: Path | None = None) -> Path:
    from sage_robot.core.paths import state_dir

    return (state or state_dir()) / TLS_DIRNAME


def wanted_names(web: WebSettings) -> tuple[list[str], list[str]]:
    """(DNS names, IP addresses) a certificate made here covers."""
    hostname = socket.gethostname() or "localhost"
    dns = [hostname, f"{hostname}.local", "localhost"]
    ips = ["127.0.0.1", "::1", *lan_addresses()]
    for extra in (web.public_host, web.host):
        if not extra or extra in ("0.0.0.0", "::"):
            continue
        try:
            ipaddress.ip_address(extra)
            ips.append(extra)
        except ValueError:
            dns.append(extra)
    return list(dict.fromkeys(dns)), list(dict.fromkeys(ips))


def cert_names(cert_pem: bytes) -> tuple[list[str], list[str]]:
    """(DNS names, IP addresses) of a PEM certificate's subjectAltName."""
    from cryptography import x509

    cert = x509.load_pem_x509_certificate(cert_pem)
    try:
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    except x509.ExtensionNotFound:
        return [], []
    return (list(san.get_values_for_type(x509.DNSName)),
            [str(ip) for ip in san.get_values_for_type(x509.IPAddress)])


def ensure_certificate(web: WebSettings, state: Path | None = None) -> CertPair:
    """The certificate to serve: the operator's, or SAGE's own (made now when missing, expiring,
    unreadable or not covering one of the machine's current addresses)."""
    if web.tls_cert or web.tls_key:
        if not (web.tls_cert and web.tls_key):
            raise ConfigError("web.tls_cert and web.tls_key go together: set both, or neither")
        cert, key = Path(web.tls_cert).expanduser(), Path(web.tls_key).expanduser()
        for what, path in (("web.tls_cert", cert), ("web.tls_key", key)):
            if not path.is_file():
                raise ConfigError(f"{what}: {path} not found")
        return CertPair(cert, key, made_here=False)
    try:
        import cryptography  # noqa: F401
    except ImportError:
        raise ConfigError(
            "web.tls: making a certificate needs the cryptography package (pip install 'sage-robot[web]'); "
            "or give web.tls_cert/web.tls_key, or set web.tls: off"
        ) from None
    folder = tls_dir(state)
    cert, key = folder / CERT_FILENAME, folder / KEY_FILENAME
    dns, ips = wanted_names(web)
    reason = _why_renew(cert, key, ips)
    if reason:
        _make_self_signed(cert, key, dns, ips)
        _log.info("made a self-signed TLS certificate", why=reason, path=str(cert), dns=dns, ips=ips)
    return CertPair(cert, key, made_here=True)


def _why_renew(cert: Path, key: Path, ips: list[str]) -> str:
    if not cert.exists() or not key.exists():
        return "first run"
    from cryptography import x509

    try:
        parsed = x509.load_pem_x509_certificate(cert.read_bytes())
    except (OSError, ValueError):
        return "the stored certificate is unreadable"
    if parsed.not_valid_after_utc - dt.timedelta(days=RENEW_BEFORE_DAYS) < dt.datetime.now(dt.timezone.utc):
        return "the stored certificate expires"
    _, has = cert_names(cert.read_bytes())
    missing = [ip for ip in ips if ip not in has]
    if missing:
        return f"new address {', '.join(missing)}"
    return ""


def _make_self_signed(cert_path: Path, key_path: Path, dns: list[str], ips: list[str]) -> None:
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([
        x509.NameAttribute(NameOID.COMMON_NAME, (dns[0] if dns else "sage")[:64]),
        x509.NameAttribute(NameOID.ORGANIZATION_NAME, "SAGE robot (self-signed)"),
    ])
    now = dt.datetime.now(dt.timezone.utc)
    alt: list[x509.GeneralName] = [x509.DNSName(d) for d in dns]
    alt += [x509.IPAddress(ipaddress.ip_address(ip)) for ip in ips]
    cert = (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - dt.timedelta(minutes=5))
        .not_valid_after(now + dt.timedelta(days=CERT_DAYS))
        .add_extension(x509.SubjectAlternativeName(alt), critical=False)
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH]), critical=False)
        .add_extension(
            x509.KeyUsage(digital_signature=True, content_commitment=False, key_encipherment=False,
                          data_encipherment=False, key_agreement=False, key_cert_sign=False,
                          crl_sign=False, encipher_only=False, decipher_only=False),
            critical=True,
        )
        .sign(key, hashes.SHA256())
    )
    cert_path.parent.mkdir(parents=True, exist_ok=True)
    key_bytes = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                  serialization.NoEncryption())
    tmp_key = key_path.with_suffix(".tmp")
    fd = os.open(tmp_key, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(key_bytes)
    os.replace(tmp_key, key_path)
    tmp_cert = cert_path.with_suffix(".tmp")
    tmp_cert.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    os.replace(tmp_cert, cert_path)


def client_context(web: WebSettings, state: Path | None = None) -> ssl.SSLContext:
    """For SAGE's own command-line clients on this machine (``sage status``, ``sage slam save``):
    trusts exactly the certificate the server serves, whatever names it has."""
    cert = Path(web.tls_cert).expanduser() if web.tls_cert else tls_dir(state) / CERT_FILENAME
    ctx = ssl.create_default_context()
    ctx.check_hostname = False  # 127.0.0.1 need not be in an operator's certificate
    ctx.verify_flags |= ssl.VERIFY_X509_PARTIAL_CHAIN  # the served leaf itself is the anchor
    with contextlib.suppress(OSError, ssl.SSLError):
        ctx.load_verify_locations(cafile=str(cert))
    return ctx


def local_url(web: WebSettings) -> str:
    """The base URL of the robot's pages from this machine (``https://127.0.0.1:PORT`` with TLS)."""
    return f"{'https' if tls_enabled(web) else 'http'}://127.0.0.1:{web.port}"


# ---------------------------------------------------------------- the plain-http redirect
class RedirectToHttps:
    """ASGI app of ``web.http_port``: every request → 308 to the same path and query on HTTPS."""

    def __init__(self, https_port: int, fallback_host: str) -> None:
        self.https_port = https_port
        self.fallback_host = fallback_host

    def location(self, host_header: str | None, path: str, query: str) -> str:
        host = self.fallback_host
        if host_header:
            with contextlib.suppress(ValueError):
                parsed = urlsplit(f"//{host_header}").hostname
                if parsed:
                    host = parsed
        port = "" if self.https_port == 443 else f":{self.https_port}"
        return f"https://{url_host(host)}{port}{path or '/'}{'?' + query if query else ''}"

    async def __call__(self, scope: dict[str, Any], receive: Any, send: Any) -> None:
        if scope["type"] == "lifespan":
            return
        if scope["type"] != "http":  # a WebSocket on the plain port: refuse it
            await send({"type": "websocket.close", "code": 1008})
            return
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope.get("headers", [])}
        target = self.location(headers.get("host"), scope.get("raw_path", b"").decode("latin-1").split("?")[0]
                               or scope.get("path", "/"), scope.get("query_string", b"").decode("latin-1"))
        body = f"Moved to {target}\n".encode()
        await send({
            "type": "http.response.start",
            "status": 308,
            "headers": [(b"location", target.encode("latin-1")), (b"content-type", b"text/plain"),
                        (b"content-length", str(len(body)).encode()), (b"cache-control", b"no-store")],
        })
        await send({"type": "http.response.body", "body": body})
