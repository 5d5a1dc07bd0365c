"""Agents with the D3IL reference agents' interface and quirks, one per family.

The CI has no copy of the reference code (ALRhub/d3il), so the tests of
``d3il_client.agents`` (export, check, serve) run against these: small networks
written here, with the reference classes' names, attributes and ``predict`` paths
(deques empty at ``reset()``, the scaler with its 1e-12, clamps, shape arithmetic on
the window, samplers as configured). Each module has ``make_agent(checkpoint=None)``.
"""
