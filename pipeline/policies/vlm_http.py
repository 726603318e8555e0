"""The VLM client's HTTP, bounded: one request whose whole exchange (connect, send, every
byte of the reply's headers and body) ends within the request's timeout, and whose reply
is read up to :data:`MAX_REPLY_BYTES`, compressed and decompressed.

The ``openai`` client's own transport bounds each socket read, not the exchange (a reply
dripping one byte a second holds it for ever) nor the bytes read (a 600 MB body, a gzip
bomb). :class:`BoundedTransport` is an ``httpx2`` transport the client is given instead:
it speaks HTTP/1.1 through :mod:`http.client`, every socket operation waiting at most the
time left until the deadline (the TLS handshake's, each at most the time left when the
connection opened), one connection per request (no keep-alive: a half-read
reply never leaks into the next). Proxies come from the environment as the client's would
(``HTTP(S)_PROXY``, ``NO_PROXY``; ``https`` through a CONNECT tunnel). Faults are raised
as ``httpx2`` errors the client maps to its own (``ReadTimeout`` to a timeout, ``ConnectError``
to a connection failure), and a reply over the limit as :class:`ReplyTooLarge`.
"""

from __future__ import annotations

import http.client
import io
import socket
import ssl
import time
import urllib.request
import zlib
from typing import Any
from urllib.parse import urlsplit

import httpx2

from schemas.errors import PolicyError

#: Largest reply read (bytes, before and after decompression): an answer is ~1 KB of JSON;
#: 4 MiB holds any chat completion of at most 4,096 tokens many times over.
MAX_REPLY_BYTES = 4 * 2**20
_CHUNK = 65_536
#: Content encodings decoded (each bounded): what the request's Accept-Encoding offers.
_DECODERS = {"gzip": 16 + zlib.MAX_WBITS, "x-gzip": 16 + zlib.MAX_WBITS, "deflate": zlib.MAX_WBITS}
#: Hop-by-hop and encoding headers not passed on (the body handed on is whole and decoded).
_DROPPED = {"content-encoding", "transfer-encoding", "content-length", "connection", "keep-alive"}


#: Longest wait of the endpoint check before a run's first episode (seconds; less if the
#: request timeout is shorter).
REACH_TIMEOUT_S = 10.0


class ReplyTooLarge(Exception):
    """A reply longer than :data:`MAX_REPLY_BYTES` (as sent, or once decompressed)."""


class UnreadableReply(httpx2.DecodingError):
    """A reply in an encoding not asked for, or whose compressed body does not decode."""


class _DeadlineIO(io.RawIOBase):
    """A socket's reads, each waiting at most until the deadline."""

    def __init__(self, owner: _DeadlineSocket) -> None:
        self._owner = owner

    def readable(self) -> bool:
        return True

    def readinto(self, buffer: Any) -> int:
        sock = self._owner.sock
        sock.settimeout(_left(self._owner.deadline))
        return sock.recv_into(buffer)

    def close(self) -> None:
        if not self.closed:
            self._owner.release()
        super().close()


class _DeadlineSocket:
    """What :mod:`http.client` uses of a socket (send, read through a file, close), bounded by
    the deadline. As a socket's, the files it made keep it open until they are closed too."""

    def __init__(self, sock: socket.socket, deadline: float) -> None:
        self.sock, self.deadline = sock, deadline
        self._users = 1  # this object and each open file

    def sendall(self, data: bytes) -> None:
        self.sock.settimeout(_left(self.deadline))  # sendall's timeout bounds the whole send
        self.sock.sendall(data)

    def makefile(self, mode: str = "rb", *args: Any, **kwargs: Any) -> io.BufferedReader:
        self._users += 1
        return io.BufferedReader(_DeadlineIO(self))

    def release(self) -> None:
        self._users -= 1
        if self._users == 0:
            self.sock.close()

    def close(self) -> None:
        if self._users > 0:
            self.release()


def _left(deadline: float) -> float:
    left = deadline - time.monotonic()
    if left <= 0:
        raise TimeoutError("the request's time is up")
    return left


class _DeadlineHTTP(http.client.HTTPConnection):
    """A connection whose socket, once connected, obeys ``deadline``."""

    deadline = 0.0

    def connect(self) -> None:
        super().connect()
        self.sock = _DeadlineSocket(self.sock, self.deadline)


class _DeadlineHTTPS(http.client.HTTPSConnection):
    """As :class:`_DeadlineHTTP`, once tunnelled and TLS-wrapped."""

    deadline = 0.0

    def connect(self) -> None:
        super().connect()
        self.sock = _DeadlineSocket(self.sock, self.deadline)


def _connection(url: httpx2.URL, deadline: float, context: ssl.SSLContext) -> tuple[http.client.HTTPConnection, str]:
    """A connection to ``url``'s host (or its proxy) whose socket obeys ``deadline``; the request target."""
    secure = url.scheme == "https"
    port = url.port or (443 if secure else 80)
    target = url.raw_path.decode("ascii")
    proxy = None if urllib.request.proxy_bypass(url.host) else urllib.request.getproxies().get(url.scheme)
    host = url.host
    if proxy:
        parts = urlsplit(proxy if "://" in proxy else f"http://{proxy}")
        host, port, target = parts.hostname or "", parts.port or 80, target if secure else str(url)
    conn: _DeadlineHTTP | _DeadlineHTTPS
    if secure:
        conn = _DeadlineHTTPS(host, port, timeout=_left(deadline), context=context)
        if proxy:
            conn.set_tunnel(url.host, url.port or 443)
    else:
        conn = _DeadlineHTTP(host, port, timeout=_left(deadline))
    conn.deadline = deadline
    return conn, target


def _read_body(response: http.client.HTTPResponse, encoding: str) -> bytes:
    """The reply's body, decoded, at most :data:`MAX_REPLY_BYTES` either way."""
    if encoding not in ("", "identity") and encoding not in _DECODERS:
        raise UnreadableReply(f"the reply's content encoding {encoding[:40]!r} was not asked for")
    decoder = zlib.decompressobj(_DECODERS[encoding]) if encoding in _DECODERS else None
    raw = out = 0
    parts: list[bytes] = []
    while True:
        chunk = response.read(_CHUNK)
        if not chunk:
            break
        raw += len(chunk)
        if raw > MAX_REPLY_BYTES:
            raise ReplyTooLarge(f"the reply is longer than {MAX_REPLY_BYTES:,} bytes")
        if decoder is not None:
            try:
                chunk = decoder.decompress(chunk, MAX_REPLY_BYTES - out + 1)
            except zlib.error as exc:
                raise UnreadableReply(f"the reply's {encoding} body does not decode: {exc}") from None
            if decoder.unconsumed_tail:
                raise ReplyTooLarge(f"the reply is longer than {MAX_REPLY_BYTES:,} bytes once decompressed")
        out += len(chunk)
        if out > MAX_REPLY_BYTES:
            raise ReplyTooLarge(f"the reply is longer than {MAX_REPLY_BYTES:,} bytes once decompressed")
        parts.append(chunk)
    return b"".join(parts)


class BoundedTransport(httpx2.BaseTransport):
    """An ``httpx2`` transport whose every request ends within ``timeout_s`` (module docstring)."""

    def __init__(self, timeout_s: float) -> None:
        self.timeout_s = float(timeout_s)
        self._context = ssl.create_default_context()

    def handle_request(self, request: httpx2.Request) -> httpx2.Response:
        deadline = time.monotonic() + self.timeout_s
        body = request.read()
        headers = {k.decode("latin-1"): v.decode("latin-1") for k, v in request.headers.raw}
        headers = {k: v for k, v in headers.items() if k.lower() not in ("accept-encoding", "connection")}
        headers["Accept-Encoding"] = "gzip, deflate"
        headers["Connection"] = "close"
        try:
            conn, target = _connection(request.url, deadline, self._context)
        except TimeoutError:
            raise httpx2.ConnectTimeout("no connection within the timeout", request=request) from None
        response: http.client.HTTPResponse | None = None
        try:
            try:
                conn.request(request.method, target, body=body, headers=headers)
                response = conn.getresponse()
                content = _read_body(response, (response.getheader("Content-Encoding") or "").strip().lower())
            except TimeoutError:
                raise httpx2.ReadTimeout("no whole reply within the timeout", request=request) from None
            except (OSError, http.client.HTTPException) as exc:
                raise httpx2.ConnectError(f"{type(exc).__name__}: {exc}", request=request) from None
            kept = [(k, v) for k, v in response.getheaders() if k.lower() not in _DROPPED]
            return httpx2.Response(response.status, headers=kept, content=content, request=request)
        finally:
            if response is not None:
                response.close()
            conn.close()


def bounded_client(timeout_s: float) -> httpx2.Client:
    """An ``httpx2`` client (for ``openai.OpenAI(http_client=...)``) over :class:`BoundedTransport`."""
    return httpx2.Client(transport=BoundedTransport(timeout_s), timeout=timeout_s)


def check_reachable(url: str, timeout_s: float, shown: str) -> None:
    """PolicyError naming ``shown`` unless a connection to ``url``'s host (through its proxy,
    TLS handshake included) opens within ``timeout_s``: checked once before a run's first
    episode, so that an unreachable endpoint fails the run at once, not every episode."""
    deadline = time.monotonic() + min(timeout_s, REACH_TIMEOUT_S)
    try:
        conn, _ = _connection(httpx2.URL(url), deadline, ssl.create_default_context())
        try:
            conn.connect()
        finally:
            conn.close()
    except (OSError, http.client.HTTPException, httpx2.InvalidURL, ValueError) as exc:
        reason = "no connection within the timeout" if isinstance(exc, TimeoutError) else f"{type(exc).__name__}: {exc}"
        raise PolicyError(f"{shown}: cannot reach the VLM endpoint ({reason}); nothing was evaluated") from None
