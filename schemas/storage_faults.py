"""An object store's failures (an unreachable endpoint, no credentials, a refused request),
recognised and described without importing its client.

botocore, aiobotocore and s3fs are optional and heavy; ``schemas`` imports none of them,
so their exceptions are recognised by the module that defines them and described by class
name and the attributes botocore documents (``kwargs``, ``response``). The storage layer
(:mod:`catalog.store.storage`) turns them into :class:`schemas.errors.StorageError` naming the
URL; the command-line layer (:mod:`schemas.cli`) gives any that escape one line and exit 2.
"""

from __future__ import annotations

from urllib.parse import urlsplit

#: Top-level packages whose exceptions are an object store's failures (aiohttp: s3fs's
#: HTTP client, whose ClientPayloadError is a body shorter than its announced length;
#: fsspec: its FSTimeoutError).
STORAGE_PACKAGES = ("botocore", "aiobotocore", "s3fs", "aiohttp", "fsspec")
_TIMEOUTS = ("TimeoutError", "FSTimeoutError", "AioReadTimeoutError", "ServerTimeoutError")
_CREDENTIALS = ("NoCredentialsError", "PartialCredentialsError", "CredentialRetrievalError",
                "NoAuthTokenError", "UnauthorizedSSOTokenError")
_UNREACHABLE = ("EndpointConnectionError", "ConnectTimeoutError", "ReadTimeoutError", "ConnectionClosedError",
                "ProxyConnectionError", "SSLError", "HTTPClientError")
#: How to give credentials, said when none were found.
CREDENTIALS_HINT = ("set AWS_ACCESS_KEY_ID and AWS_SECRET_ACCESS_KEY (and AWS_ENDPOINT_URL for an S3-compatible "
                    "server), or pass key=, secret= and endpoint_url= in a UPath")


def _chain(exc: BaseException) -> list[BaseException]:
    """``exc`` and what it was raised from or while handling (not past ``raise ... from None``)."""
    found: list[BaseException] = []
    current: BaseException | None = exc
    while current is not None and len(found) < 8:
        found.append(current)
        current = current.__cause__ or (None if current.__suppress_context__ else current.__context__)
    return found


def _raised_in_storage(exc: BaseException) -> bool:
    """The innermost frame of ``exc``'s traceback is the object-store client's code (a
    builtin exception it raised: a TimeoutError from aiohttp, an IndexError of s3fs's)."""
    tb = exc.__traceback__
    while tb is not None and tb.tb_next is not None:
        tb = tb.tb_next
    name = tb.tb_frame.f_globals.get("__name__", "") if tb is not None else ""
    return str(name).split(".")[0] in STORAGE_PACKAGES


def is_storage_fault(exc: BaseException) -> bool:
    """True for an exception of the object-store client: defined by one of its packages, raised
    in their code, or raised while handling such an exception."""
    return any(_raised_in_storage(e) or any(str(kind.__module__).split(".")[0] in STORAGE_PACKAGES
                                            for kind in type(e).__mro__) for e in _chain(exc))


def _names(exc: BaseException) -> set[str]:
    return {kind.__name__ for kind in type(exc).__mro__}


def _endpoint(exc: BaseException) -> str:
    """``scheme://host:port`` of the endpoint an error names, or ``""``."""
    kwargs = getattr(exc, "kwargs", None)
    url = kwargs.get("endpoint_url") if isinstance(kwargs, dict) else None
    if not isinstance(url, str):
        return ""
    parts = urlsplit(url)
    return f"{parts.scheme}://{parts.netloc}" if parts.netloc else url


def describe_storage_fault(exc: BaseException) -> str:
    """The cause of an object store's failure in a few words (no URL: the caller names it)."""
    names = _names(exc)
    if names & set(_CREDENTIALS):
        return f"no credentials for the object store ({CREDENTIALS_HINT})"
    if names & set(_UNREACHABLE):
        endpoint = _endpoint(exc)
        return f"cannot reach the object store{' at ' + endpoint if endpoint else ''} ({type(exc).__name__})"
    if any(_names(e) & set(_TIMEOUTS) for e in _chain(exc)):
        return "the object store did not answer in time (a request's deadline passed)"
    if "ClientPayloadError" in names:
        return "the object store's reply was cut short (fewer bytes than it announced)"
    response = getattr(exc, "response", None)
    error = response.get("Error") if isinstance(response, dict) else None
    if isinstance(error, dict) and error.get("Code"):
        return f"the object store refused: {error.get('Code')}: {error.get('Message') or ''}".rstrip(": ")
    text = " ".join(str(exc).split())
    return f"object store error: {type(exc).__name__}{': ' + text if text else ''}"
