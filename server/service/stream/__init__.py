"""The stream protocol transport (PROTOCOL.md): the listener, the handshake, and per
connection a reader and a writer."""
