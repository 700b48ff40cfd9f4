"""The package's version: read by ``pyproject.toml`` (the distribution's version), the CLI and the service."""

__version__ = "0.1.0"
