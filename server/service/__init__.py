"""The render service, by role: `http/` and `stream/` are the two transports, `render/` the
render worker and the render process it supervises (the only one with a GL context); the
modules here are what they share (sessions, admission, config, metrics, logs). See
ARCHITECTURE.md."""
