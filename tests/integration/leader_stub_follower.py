"""A tiny follower stand-in for the leader's integration tests (run as a process).

Over real Zenoh it answers commands with Feedback whose z_e follows the command's
reference with a first-order lag (time constant ``TAU``), publishing at 50 Hz. Each
feedback message is held back for the current backward delay before it is published
(a real delay, stamped with its creation time): ``delay1`` until ``switch_s``, then
``delay2``; after ``silent_s`` no more feedback is published (the process stays present),
and it exits after ``total_s``. Usage::

    python leader_stub_follower.py ROBOT_ID CONNECT_ENDPOINT delay1 delay2 switch_s silent_s total_s
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # tests/: the delay line

from bipedtele.config.sections import NetworkConfig
from bipedtele.link.delayestimate import DelayEstimator
from bipedtele.link.delaymodels import ConstDelay
from bipedtele.link.drops import DropCounter
from bipedtele.link.gate import SequenceGate
from bipedtele.link.messages import Command, Feedback, new_session_id
from bipedtele.link.receivers import LatestReceiver
from bipedtele.link.transport import Keys, Publishers, declare_presence
from bipedtele.link.zenohsession import open_session
from delayline import DelayLine

TAU = 0.3  # s


def main(argv: list[str]) -> int:
    robot, endpoint = argv[0], argv[1]
    delay1, delay2, switch_s, silent_s, total_s = (float(a) for a in argv[2:7])
    keys = Keys(robot)
    sid = new_session_id()
    h1 = DelayEstimator(1.0)
    with (
        open_session(NetworkConfig(connect=[endpoint])) as session,
        Publishers(session, keys) as pubs,
        declare_presence(session, keys, "follower"),
        LatestReceiver(session, keys.cmd, Command, DropCounter("stub"), SequenceGate(), estimator=h1) as rx,
    ):
        line: DelayLine[Feedback] = DelayLine(0.0)
        z = [0.0, 0.0]
        t0 = time.time()
        seq = 0
        next_fb = t0
        while (now := time.time()) - t0 < total_s:
            got = rx.latest()
            ref = got.msg.ref if got is not None and got.msg.enable else [0.0, 0.0]
            if now >= next_fb:
                dt = 0.02
                next_fb += dt
                z = [z[i] + (ref[i] - z[i]) * dt / TAU for i in range(2)]
                elapsed = now - t0
                if elapsed < silent_s:
                    seq += 1
                    fb = Feedback(
                        sid=sid,
                        seq=seq,
                        t=now,
                        z_e=list(z),
                        z_r=list(z),
                        eta=list(z),
                        ref=list(ref),
                        h1_s=h1.value(now) or 0.0,
                        state="walking" if got else "standing",
                        cmd_seq=got.msg.seq if got else 0,
                    )
                    line.model = ConstDelay(delay1 if elapsed < switch_s else delay2)
                    line.push(now, fb)
            for fb in line.pop_ready(time.time()):
                pubs.feedback.put(fb)
            time.sleep(0.002)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
