"""The HTTP transport: the listener, the request handler, its routes and the viewer page."""
