"""Replay delay models with Linux netem on the two ends of a veth pair.

h1 (leader -> follower) is the netem delay on the leader's end (its egress), h2 on the
follower's end. A constant model is one qdisc setting; ``uniform``/``normal`` models map
to netem's own jitter (``delay MEAN HALFWIDTH`` / ``delay MEAN STD distribution normal``);
a trace is replayed by ``tc qdisc change`` at the trace's own sample times (looped like
:class:`~bipedtele.link.delaymodels.TraceDelay`). netem applies a packet's delay when the
packet is queued, so each packet sees the delay in force when it was sent, like the
user-space proxy.

The replay runs one ``tc -n NS -force -batch -`` process per end (no process per
change) and writes each change at its time on the clock of the run (``t0`` in unix
seconds, the same origin as the proxy's ``--t0``).
"""

from __future__ import annotations

import heapq
import logging
import math
import subprocess
import threading
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import IO

from bipedtele.link.delaymodels import ConstDelay, DelayModel, NormalDelay, TraceDelay, UniformDelay
from bipedtele.link.impairments import GilbertElliott, RandomLoss, parse_loss, parse_queue, parse_rate
from bipedtele.tools.netns import FOLLOWER, LEADER, VethLink

__all__ = ["NETEM_LIMIT", "NetemReplayer", "impairment_args", "netem_args", "replay_times", "schedule"]

LOG = logging.getLogger(__name__)

# Queue length [packets]: a few seconds of this project's traffic at the largest delays.
NETEM_LIMIT = 10000


def _us(seconds: float) -> str:
    return f"{round(seconds * 1e6)}us"


def impairment_args(loss: str | None = None, rate: str | None = None, queue: str | None = None) -> list[str]:
    """Netem options for loss, a rate cap and its queue, from the packet emulator's specs.

    The same specs as ``bipedtele link-emu`` (:mod:`bipedtele.link.impairments`), so a netem
    kernel runs the conditions the user-space emulator runs: random loss (``1%``) becomes
    ``loss random 1%``; Gilbert-Elliott (``ge:p=1%,r=30%,bad=100%,good=0%``) becomes
    netem's ``loss gemodel p r 1-h 1-k`` (h, k: the probability that a packet gets
    *through* in the bad and good state); a rate (``600kbit``) becomes ``rate 600000bit``;
    the queue (``64kB``), which netem counts in packets, becomes ``limit`` = bytes / 1500
    (at least 1).

    Raises
    ------
    ConfigError
        A bad spec (one line, as the emulator says it).
    """
    args: list[str] = []
    if loss:
        model = parse_loss(loss)
        if isinstance(model, RandomLoss):
            args += ["loss", "random", _pct(model.p)]
        elif isinstance(model, GilbertElliott):
            args += ["loss", "gemodel", _pct(model.p), _pct(model.r), _pct(model.loss_bad), _pct(model.loss_good)]
    if rate:
        bps = parse_rate(rate)
        if bps is not None:
            args += ["rate", f"{round(bps)}bit"]
    if queue:
        args += ["limit", str(max(1, parse_queue(queue) // 1500))]
    return args


def _pct(p: float) -> str:
    return f"{100.0 * p:g}%"


def netem_args(model: DelayModel, t: float = 0.0, extra: Sequence[str] = ()) -> list[str]:
    """Netem options realising ``model`` at time ``t`` [s] of the run.

    Parameters
    ----------
    model : DelayModel
        A const, uniform, normal or trace model.
    t : float
        Time since the run's origin [s] (traces only).
    extra : sequence of str
        More netem options (:func:`impairment_args`: loss, rate, limit); a ``limit`` there
        replaces the default one.
    """
    if isinstance(model, UniformDelay):
        args = ["delay", _us(model.mean), _us(model.half_width)]
    elif isinstance(model, NormalDelay):
        args = ["delay", _us(model.mean), _us(model.std), "distribution", "normal"]
    elif isinstance(model, TraceDelay | ConstDelay):
        args = ["delay", _us(model.delay_s(t))]
    else:
        raise TypeError(f"netem cannot realise a {type(model).__name__}")
    if "limit" in extra:
        return [*args, *extra]
    return [*args, *extra, "limit", str(NETEM_LIMIT)]


def replay_times(model: DelayModel, t_end: float = math.inf) -> Iterator[float]:
    """Return the times in ``(0, t_end]`` [s], in order, at which ``model``'s qdisc must change.

    A trace changes at each of its rows, looped over its period: at every ``t`` where
    :meth:`TraceDelay.delay_s` lands on a row (``t`` = a row's time modulo the period, plus
    whole periods). Other models never change.
    """
    if not isinstance(model, TraceDelay):
        return
    offsets = sorted({t % model.period for t in model.t})
    k = 0
    while True:
        for off in offsets:
            t = k * model.period + off
            if t <= 0.0:
                continue
            if t > t_end:
                return
            yield t
        k += 1


def _command(link: VethLink, side: str, verb: str, args: list[str]) -> list[str]:
    return ["tc", "-n", link.ns[side], "qdisc", verb, "dev", link.dev[side], "root", "netem", *args]


@dataclass(frozen=True)
class Step:
    """One scheduled ``tc`` command: ``t`` [s] after the origin, on one side."""

    t: float
    side: str
    command: list[str]


def schedule(
    link: VethLink,
    forward: DelayModel,
    backward: DelayModel,
    t_end: float,
    extra: Mapping[str, Sequence[str]] | None = None,
) -> Iterator[Step]:
    """Every ``tc`` command of a replay, in time order: the two ``add`` at 0, then changes.

    Parameters
    ----------
    link : VethLink
        The namespaces and devices.
    forward, backward : DelayModel
        h1 (on the leader's end) and h2 (on the follower's end).
    t_end : float
        Length of the replay [s] (infinite: the replay never ends by itself).
    extra : mapping, optional
        Side (``leader``, ``follower``) -> more netem options for that end's egress
        (:func:`impairment_args`), kept on every change.
    """
    models = {LEADER: forward, FOLLOWER: backward}
    more = {side: list((extra or {}).get(side, ())) for side in models}
    for side, model in models.items():
        yield Step(0.0, side, _command(link, side, "add", netem_args(model, 0.0, more[side])))

    def tagged(order: int, side: str) -> Iterator[tuple[float, int, str]]:
        for t in replay_times(models[side], t_end):
            yield t, order, side

    changes = heapq.merge(*(tagged(order, side) for order, side in enumerate(models)))
    for t, _, side in changes:
        yield Step(t, side, _command(link, side, "change", netem_args(models[side], t, more[side])))


class NetemReplayer:
    """Applies a :func:`schedule` in real time, from a thread.

    Parameters
    ----------
    link : VethLink
        Created namespaces.
    forward, backward : DelayModel
        h1 and h2.
    t0 : float
        Origin of the models (unix time [s]).
    t_end : float
        Replay length [s] (default: until :meth:`stop`).
    extra : mapping, optional
        Side -> more netem options (loss, rate, limit; :func:`impairment_args`).
    """

    def __init__(
        self,
        link: VethLink,
        forward: DelayModel,
        backward: DelayModel,
        t0: float,
        t_end: float = math.inf,
        extra: Mapping[str, Sequence[str]] | None = None,
    ) -> None:
        self.link, self.forward, self.backward = link, forward, backward
        self.extra = extra
        self.t0, self.t_end = t0, t_end
        self.changes = 0
        self.late_s: list[float] = []
        self._stop = threading.Event()
        self._batch: dict[str, subprocess.Popen[str]] = {}
        self._thread: threading.Thread | None = None

    def start(self) -> NetemReplayer:
        """Add both qdiscs now (raises ``RuntimeError`` with tc's message if one fails), then replay."""
        steps = schedule(self.link, self.forward, self.backward, self.t_end, self.extra)
        for _ in range(2):
            step = next(steps)
            res = subprocess.run(step.command, capture_output=True, text=True, timeout=20, check=False)
            if res.returncode != 0:
                err = (res.stderr.strip().splitlines() or ["failed"])[0]
                raise RuntimeError(f"`{' '.join(step.command)}`: {err}")
        for side in (LEADER, FOLLOWER):
            self._batch[side] = subprocess.Popen(
                ["tc", "-n", self.link.ns[side], "-force", "-batch", "-"],
                stdin=subprocess.PIPE,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.PIPE,
                text=True,
            )
            threading.Thread(target=self._log_errors, args=(side,), daemon=True).start()
        self._thread = threading.Thread(target=self._run, args=(steps,), name="netem-replay", daemon=True)
        self._thread.start()
        return self

    def _log_errors(self, side: str) -> None:
        stream: IO[str] | None = self._batch[side].stderr
        if stream is None:
            return
        for line in stream:
            LOG.warning("netem replay (%s end): %s", side, line.strip())

    def _run(self, steps: Iterator[Step]) -> None:
        for step in steps:
            wait = self.t0 + step.t - time.time()
            if wait > 0 and self._stop.wait(wait):
                return
            if self._stop.is_set():
                return
            stdin = self._batch[step.side].stdin
            if stdin is None:
                return
            try:
                # the batch syntax is the command line without the leading `tc -n NS`
                stdin.write(" ".join(step.command[3:]) + "\n")
                stdin.flush()
            except (BrokenPipeError, OSError):
                LOG.error("netem replay: tc batch on the %s end stopped", step.side)
                return
            self.changes += 1
            self.late_s.append(max(0.0, time.time() - (self.t0 + step.t)))
            del self.late_s[:-1000]

    def stop(self) -> None:
        """Stop replaying (the qdiscs go with the namespaces)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        for proc in self._batch.values():
            if proc.stdin is not None:
                proc.stdin.close()
            try:
                proc.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=5.0)
        LOG.info("netem replay: %d changes applied", self.changes)

    def __enter__(self) -> NetemReplayer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
