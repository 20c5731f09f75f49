"""Vantage: ordinary cameras as measuring instruments."""

__version__ = "0.1.0"
