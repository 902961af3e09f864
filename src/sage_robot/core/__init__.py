"""Core: bus, clock, messages, geometry, config, logging. Imports nothing else of the project."""
