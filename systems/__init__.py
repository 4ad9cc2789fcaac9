"""The capture systems, one package each, found by the engine through the ``mocapflow.systems`` entry points
(pyproject.toml): each package's ``SYSTEM`` declares everything it adds (registry.System). A user's system is
found the same way, or through a catalog's ``plugins:`` (docs/adding-a-system.md)."""
