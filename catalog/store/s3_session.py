"""The S3 client's HTTP session with a deadline for each whole request.

botocore's ``connect_timeout`` and ``read_timeout`` (:data:`catalog.store.storage.CLIENT_TIMEOUTS`)
bound each wait on the socket, so an endpoint that trickles a byte a second is never cut by
them. aiohttp's ``total`` timeout bounds the whole request (connecting, sending, reading the
reply); aiobotocore builds its session's timeout from the first two only, so this session
adds the third. :data:`REQUEST_TOTAL_S` is generous: the largest request Dyana makes is one
upload part of s3fs (50 MiB), 50 s at 1 MiB/s.
"""

from __future__ import annotations

from typing import Any

import aiohttp
from aiobotocore.httpsession import AIOHTTPSession

#: Seconds one request to the object store may take in all.
REQUEST_TOTAL_S = 300.0


class BoundedSession(AIOHTTPSession):
    """aiobotocore's session, each request bounded by :data:`REQUEST_TOTAL_S` in all."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        socket_waits: aiohttp.ClientTimeout = vars(self)["_timeout"]  # aiobotocore's, from the client's config
        self._timeout = aiohttp.ClientTimeout(total=REQUEST_TOTAL_S, sock_connect=socket_waits.sock_connect,
                                              sock_read=socket_waits.sock_read)
