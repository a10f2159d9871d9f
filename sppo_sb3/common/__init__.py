"""Machinery shared by every algorithm of the package: costs, safety metrics."""
