"""The printer link's errors: one tree, so a caller may catch any of them as one."""

from __future__ import annotations


class PrinterLinkError(Exception):
    """Base of every error the printer link raises."""


class TransportError(PrinterLinkError, ConnectionError):
    """The port could not be opened, vanished, or failed while reading or writing."""


class LinkError(PrinterLinkError, ConnectionError):
    """The link to the printer failed: port lost, printer silent, halted or emergency stop."""


class StreamCancelled(PrinterLinkError):
    """The stream was cancelled: ``send()`` no longer accepts job lines."""
