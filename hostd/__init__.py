"""hostd: printer-host service for 4D printing (daemon, printer link, web)."""

from pipeline import __version__

__all__ = ["__version__"]
