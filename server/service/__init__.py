"""The render service: HTTP API, streaming socket, sessions, scheduler, metrics (no GL here
except in `worker`, whose render thread owns the context). See ARCHITECTURE.md."""
