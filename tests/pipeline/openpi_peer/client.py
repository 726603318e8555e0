"""Runs in the openpi-client venv (numpy<2, no Dyana): drives a `pipeline serve --protocol
openpi` with openpi_client.websocket_client_policy, as an openpi user's robot loop does.

    python client.py URL REQUESTS OUT

REQUESTS holds {"requests": [observation dicts]} (decoded with openpi's own
msgpack_numpy); OUT gets {"metadata", "actions": [...], "error"}: the server's metadata,
each reply's actions, and the RuntimeError openpi_client raises for a request without
its state (the server's error frame)."""

import sys

from openpi_client import msgpack_numpy
from openpi_client.websocket_client_policy import WebsocketClientPolicy

url, requests_path, out_path = sys.argv[1:4]
with open(requests_path, "rb") as f:
    requests = msgpack_numpy.unpackb(f.read())["requests"]

policy = WebsocketClientPolicy(host=url)
policy.reset()  # openpi's reset is local: nothing goes on the wire
actions = [policy.infer(request)["actions"] for request in requests]
bad = {k: v for k, v in requests[0].items() if k != "observation/state"}
broken = WebsocketClientPolicy(host=url)
try:
    broken.infer(bad)
    error = None
except RuntimeError as exc:
    error = str(exc)
with open(out_path, "wb") as f:
    f.write(msgpack_numpy.packb({"metadata": policy.get_server_metadata(), "actions": actions, "error": error}))
