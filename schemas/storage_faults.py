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
#: HTTP client, whose ClientPayloadError is a body shorter than its announced length).
STORAGE_PACKAGES = ("botocore", "aiobotocore", "s3fs", "aiohttp")
_CREDENTIALS = ("NoCredentialsError", "PartialCredentialsError", "CredentialRetrievalError",
                "NoAuthTokenError", "UnauthorizedSSOTokenError")
_UNREACHABLE = ("EndpointConnectionError", "ConnectTimeoutError", "ReadTimeoutError", "ConnectionClosedError",
                "ProxyConnectionError", "SSLError", "HTTPClientError")
#: How to give credentials, said when none were found.
CREDENTIALS_HINT = ("set AWS_ACCESS_KEY_ID and AWS_SECRET_ACCESS_KEY (and AWS_ENDPOINT_URL for an S3-compatible "
                    "server), or pass key=, secret= and endpoint_url= in a UPath")


def is_storage_fault(exc: BaseException) -> bool:
    """True for an exception raised by the object-store client (by its defining module)."""
    return any(str(kind.__module__).split(".")[0] in STORAGE_PACKAGES for kind in type(exc).__mro__)


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
    if "ClientPayloadError" in names:
        return "the object store's reply was cut short (fewer bytes than it announced)"
    response = getattr(exc, "response", None)
    error = response.get("Error") if isinstance(response, dict) else None
    if isinstance(error, dict) and error.get("Code"):
        return f"the object store refused: {error.get('Code')}: {error.get('Message') or ''}".rstrip(": ")
    text = " ".join(str(exc).split())
    return f"object store error: {type(exc).__name__}{': ' + text if text else ''}"
