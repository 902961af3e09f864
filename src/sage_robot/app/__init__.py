"""App layer: launch profiles, the supervisor (launcher), node registry."""
