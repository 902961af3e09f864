"""The `sage` command."""
