"""The package's version, importable without importing the library."""

__all__ = ["__version__"]

#: The release, as in ``pyproject.toml``.
__version__ = "0.1.0"
