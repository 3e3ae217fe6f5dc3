"""Configuration.

Typed TOML profiles, their sections and the checks on every field (docs/architecture.md).
"""
