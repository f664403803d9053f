"""The package version, in a module of its own so that :mod:`dtalign.cli`
can read it without importing the package root (and setuptools can parse it)."""

__version__ = "0.1.0"
