"""bipedtele: bilateral teleoperation of a biped (NAO) robot under time-varying delays.

The core package (folder ``common/``): messages, clock and delay estimation, transport,
control math, configuration, recording and the command-line interface. The leader
(``bipedtele.leader``) and follower (``bipedtele.follower``) depend on it, never the reverse.
"""

__version__ = "0.1.0"
