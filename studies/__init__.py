"""Thin, deterministic design-study scripts built on the public API."""
