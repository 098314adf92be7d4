"""Thin command-line layer: parse, call the library, report. The only package that prints."""
