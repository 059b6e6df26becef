"""Printing: the printer connection, the just-in-time runner, the print's owner and its commands."""
