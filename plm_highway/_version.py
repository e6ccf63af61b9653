"""The package version, in a module of its own: lower rooms (io) read it without importing the package root,
whose import registers the env."""

__version__ = "0.1.0"
