"""Policies over the network: the dyana/1 wire protocol, the server and the client, and openpi's protocol both ways."""
