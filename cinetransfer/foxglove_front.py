"""The public door of the live Foxglove server: subprotocol names and the access check.

foxglove-sdk's server speaks the Foxglove WebSocket protocol under the subprotocol name
`foxglove.sdk.v1` only and answers HTTP 400 to a client that offers the long-standing name
`foxglove.websocket.v1` (Lichtblick, older Foxglove apps, foxglove_bridge-era tools). The two
names are the same protocol. So the SDK server listens on an ephemeral loopback port and this
front listens where the user asked: it reads each client's HTTP upgrade request, answers 401 when
a credential is configured and not presented, renames an offered `foxglove.websocket.v1` to
`foxglove.sdk.v1` on the way in and back on the way out, then copies bytes both ways untouched.

The credential is a bearer token: `Authorization: Bearer TOKEN` or `?token=TOKEN` in the URL
(a browser's WebSocket cannot set headers; Foxglove takes the URL as typed). With a certificate
and key (`tls`) the front speaks TLS (`wss://`), so the token does not cross the network in clear.
"""
from __future__ import annotations

import hmac
import ipaddress
import logging
import select
import socket
import ssl
import threading
from urllib.parse import parse_qs, urlsplit

log = logging.getLogger("cinetransfer.monitor.foxglove")

SDK_PROTOCOL = "foxglove.sdk.v1"
LEGACY_PROTOCOL = "foxglove.websocket.v1"
#: the subprotocols a client may offer, in our order of preference
PROTOCOLS = (SDK_PROTOCOL, LEGACY_PROTOCOL)
MAX_HEAD = 16 * 1024
HANDSHAKE_TIMEOUT_S = 10.0


class HandshakeError(ValueError):
    """A request the front refuses: (HTTP status, one-line reason)."""

    def __init__(self, status: int, reason: str) -> None:
        super().__init__(reason)
        self.status = status


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def check_exposure(host: str, token: str | None) -> None:
    """Only loopback without a credential: anyone who reaches the port sees the rig's topics."""
    if not is_loopback(host) and not token:
        raise ValueError(f"refusing to serve Foxglove on {host}: not loopback and no access token configured "
                         f"(--token-file, or the CINETRANSFER_FOXGLOVE_TOKEN environment variable)")


def split_head(head: bytes) -> tuple[str, list[tuple[str, str]]]:
    """An HTTP head as (start line, [(name, value)]), header names as sent."""
    lines = head.decode("latin-1").split("\r\n")
    headers = []
    for line in lines[1:]:
        name, sep, value = line.partition(":")
        if sep:
            headers.append((name.strip(), value.strip()))
    return lines[0], headers


def join_head(start: str, headers: list[tuple[str, str]]) -> bytes:
    return ("\r\n".join([start, *(f"{n}: {v}" for n, v in headers)]) + "\r\n\r\n").encode("latin-1")


def offered_protocols(headers: list[tuple[str, str]]) -> list[str]:
    return [p.strip() for n, v in headers if n.lower() == "sec-websocket-protocol" for p in v.split(",") if p.strip()]


def presented_token(start: str, headers: list[tuple[str, str]]) -> str:
    for n, v in headers:
        if n.lower() == "authorization" and v[:7].lower() == "bearer ":
            return v[7:].strip()
    parts = start.split(" ")
    query = parse_qs(urlsplit(parts[1]).query) if len(parts) >= 2 else {}
    return (query.get("token") or [""])[0]


def rewrite_request(head: bytes, token: str | None) -> tuple[bytes, str]:
    """The request to pass to the SDK server, and the subprotocol to answer the client with.
    Raises HandshakeError for a request to refuse."""
    start, headers = split_head(head)
    if token and not hmac.compare_digest(presented_token(start, headers).encode(), token.encode()):
        raise HandshakeError(401, "missing or wrong access token")
    offered = offered_protocols(headers)
    chosen = next((p for p in PROTOCOLS if p in offered), None)
    if chosen is None:
        raise HandshakeError(400, f"offer one of the subprotocols {', '.join(PROTOCOLS)} "
                                  f"(offered: {', '.join(offered) or 'none'})")
    kept = [(n, v) for n, v in headers if n.lower() not in ("sec-websocket-protocol", "authorization")]
    return join_head(start, kept + [("Sec-WebSocket-Protocol", SDK_PROTOCOL)]), chosen


def rewrite_response(head: bytes, chosen: str) -> bytes:
    start, headers = split_head(head)
    return join_head(start, [(n, chosen if n.lower() == "sec-websocket-protocol" else v) for n, v in headers])


def _read_head(sock: socket.socket) -> tuple[bytes, bytes]:
    """(the HTTP head up to its blank line, bytes read past it)."""
    buf = b""
    while b"\r\n\r\n" not in buf:
        chunk = sock.recv(4096)
        if not chunk:
            raise HandshakeError(400, "connection closed during the handshake")
        buf += chunk
        if len(buf) > MAX_HEAD:
            raise HandshakeError(431, "request head too large")
    head, _, rest = buf.partition(b"\r\n\r\n")
    return head, rest


def _refuse(sock: socket.socket, e: HandshakeError) -> None:
    reason = {400: "Bad Request", 401: "Unauthorized", 431: "Request Header Fields Too Large"}.get(e.status, "Error")
    body = (str(e) + "\n").encode()
    try:
        sock.sendall(f"HTTP/1.1 {e.status} {reason}\r\nContent-Type: text/plain\r\nContent-Length: {len(body)}\r\n"
                     f"Connection: close\r\n\r\n".encode() + body)
    except OSError:
        pass


def _relay(client: socket.socket, backend: socket.socket) -> None:
    """Copy bytes both ways until either side closes. One thread per connection touches both
    sockets: a TLS socket must not be read and written from two threads at once."""
    socks = [client, backend]
    try:
        while True:
            ready = [s for s in socks if isinstance(s, ssl.SSLSocket) and s.pending()]
            if not ready:
                ready, _, _ = select.select(socks, [], [])
            for src in ready:
                data = src.recv(65536)
                if not data:
                    return
                (backend if src is client else client).sendall(data)
    except OSError:
        pass
    finally:
        for s in socks:
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            s.close()


def tls_context(cert: str, key: str) -> ssl.SSLContext:
    """A server TLS context from PEM files; ValueError with the reason if they do not load."""
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    ctx.minimum_version = ssl.TLSVersion.TLSv1_2
    try:
        ctx.load_cert_chain(cert, key)
    except (OSError, ssl.SSLError) as e:
        raise ValueError(f"cannot load the TLS certificate {cert} / key {key}: {e}") from None
    return ctx


class FoxgloveFront:
    """Listens on (host, port) and hands each accepted client to the SDK server on
    127.0.0.1:`backend_port` (see the module doc). `port` 0 picks a free port (`self.port`)."""

    def __init__(self, backend_port: int, host: str = "127.0.0.1", port: int = 8765, token: str | None = None,
                 tls: tuple[str, str] | None = None) -> None:
        check_exposure(host, token)
        self.backend_port, self.token = backend_port, token or None
        self._tls = tls_context(*tls) if tls else None
        self.refused = 0
        self._sock = socket.create_server((host, port), family=socket.AF_INET6 if ":" in host else socket.AF_INET,
                                          reuse_port=False)
        self.port = self._sock.getsockname()[1]
        self._closed = threading.Event()
        self._thread = threading.Thread(target=self._accept, name="foxglove-front", daemon=True)
        self._thread.start()

    def _accept(self) -> None:
        while not self._closed.is_set():
            try:
                client, addr = self._sock.accept()
            except OSError:
                return
            threading.Thread(target=self._serve, args=(client, addr), name="foxglove-client", daemon=True).start()

    def _serve(self, client: socket.socket, addr: tuple) -> None:
        try:
            client.settimeout(HANDSHAKE_TIMEOUT_S)
            if self._tls is not None:
                client = self._tls.wrap_socket(client, server_side=True)
            head, rest = _read_head(client)
            request, chosen = rewrite_request(head, self.token)
        except (HandshakeError, OSError) as e:  # ssl.SSLError is an OSError
            self.refused += 1
            log.warning("refused a Foxglove client from %s: %s", addr[0], e)
            if isinstance(e, HandshakeError):
                _refuse(client, e)
            client.close()
            return
        try:
            backend = socket.create_connection(("127.0.0.1", self.backend_port), timeout=HANDSHAKE_TIMEOUT_S)
            backend.sendall(request + rest)
            answer, more = _read_head(backend)
            client.sendall(rewrite_response(answer, chosen) + more)
        except (HandshakeError, OSError) as e:
            log.warning("Foxglove client from %s: the server did not complete the handshake: %s", addr[0], e)
            client.close()
            return
        client.settimeout(None)
        backend.settimeout(None)
        log.info("Foxglove client from %s connected (%s)", addr[0], chosen)
        _relay(client, backend)

    def close(self) -> None:
        self._closed.set()
        try:
            self._sock.shutdown(socket.SHUT_RDWR)  # wakes the accept() in progress; close() alone does not
        except OSError:
            pass
        self._sock.close()
        self._thread.join(5.0)
