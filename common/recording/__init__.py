"""Recordings.

The MCAP recorder, its files, format, repair and schemas, and the live view (docs/recording.md).
"""
