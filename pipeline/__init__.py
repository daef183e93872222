"""The meshdeform tool: recipes, jobs over asset folders, executors, manifest, and the CLI."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("meshdeform")
except PackageNotFoundError:  # running from a source tree that was not installed
    __version__ = "0.0.0+source"
