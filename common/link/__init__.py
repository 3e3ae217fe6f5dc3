"""The link between the two nodes.

Zenoh sessions and transport, the handshake and sealing, inboxes, clocks, delay estimates, and
the emulator's impairments (docs/architecture.md).
"""
