"""Rendering in the service: jobs, the fair scheduler, the worker that supervises the render
process, and the typed messages between them."""
