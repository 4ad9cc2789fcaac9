"""The `mocapflow` command line: the top layer, above the engine (pipeline/) and the systems (systems/)."""
