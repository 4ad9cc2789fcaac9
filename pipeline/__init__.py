"""mocapflow engine: catalog, cache, storage, scheduling and the CLI."""
