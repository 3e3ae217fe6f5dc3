#!/usr/bin/env python
# -*- coding: utf-8 -*-
# ruff: noqa: UP004, UP009, UP010, UP024, UP031, SIM105
"""bipedtele NAO guard: stops the NAO when the follower's heartbeats stop.

NAOqi has no client watchdog: if the program that sends ``ALMotion.move`` dies (kill -9,
power cut, network cut), NAO keeps walking its last move. This guard runs beside the robot
and registers the qi service ``BipedteleGuard`` on NAOqi. The follower's NAOqi bridge
calls ``heartbeat(owner)`` on it at 20 Hz while it drives the robot; when no heartbeat
arrives for ``--lapse`` seconds (0.5 s by default) the guard calls ``ALMotion.stopMove``,
once per lapse (again until one call succeeds), and logs it.

Run it on the robot (best: it also covers a cut between the follower's host and NAO)::

    python nao_guard.py --url tcp://127.0.0.1:9559

or where one cannot install on the robot, on the follower's host::

    bipedtele nao-guard --naoqi-url tcp://NAO:9559

Single file, ``qi`` and the standard library only, for the robot's own Python: Python 2.7
(NAOqi 2.8) and Python 3 (NAOqi 2.9). Keep it so: no f-strings, no annotations, nothing
outside the standard library but ``qi``. Service methods:

``version() -> str``
    ``"bipedtele-guard 1"`` (the heartbeat protocol).
``heartbeat(owner) -> float``
    Arms the guard for ``owner`` (a new owner takes over); answers the lapse [s].
``release(owner) -> bool``
    ``owner`` stopped the robot itself and leaves: disarm without a stop.
``status() -> str``
    JSON: armed, owner, seconds since the last heartbeat, stops, lapse.
"""

from __future__ import absolute_import, division, print_function

import argparse
import json
import logging
import os
import signal
import sys
import threading
import time

VERSION = "bipedtele-guard 1"
SERVICE = "BipedteleGuard"
DEFAULT_URL = "tcp://127.0.0.1:9559"
DEFAULT_LAPSE_S = 0.5
CHECK_PERIOD_S = 0.01
RETRY_STOP_S = 0.2
RECONNECT_S = 2.0

LOG = logging.getLogger("bipedtele.nao_guard")
LOG.addHandler(logging.NullHandler())
_monotonic = getattr(time, "monotonic", time.time)


class Guard(object):
    """The watchdog's state: armed by heartbeats, fires ``stop()`` once per lapse.

    ``stop`` is a callable that stops the robot and raises on failure; ``clock`` a
    monotonic clock [s]. Thread-safe: heartbeats arrive on qi's threads, :meth:`check`
    runs on the watch thread.
    """

    def __init__(self, stop, lapse_s=DEFAULT_LAPSE_S, clock=_monotonic):
        self._stop = stop
        self.lapse_s = float(lapse_s)
        self._clock = clock
        self._lock = threading.Lock()
        self.armed = False
        self.owner = ""
        self.last_beat = None
        self.beats = 0
        self.stops = 0
        self.failed_stops = 0
        self._pending = False
        self._next_retry = 0.0

    def heartbeat(self, owner):
        """Take a heartbeat from ``owner`` (arming the guard); return the lapse [s]."""
        now = self._clock()
        with self._lock:
            if owner != self.owner:
                LOG.info("heartbeats from %s%s", owner, " (taking over from %s)" % self.owner if self.owner else "")
                self.owner = owner
            if not self.armed:
                LOG.info("armed by %s: NAO is stopped %.2f s after its last heartbeat", owner, self.lapse_s)
            self.armed = True
            self._pending = False
            self.last_beat = now
            self.beats += 1
        return self.lapse_s

    def release(self, owner):
        """Disarm the guard when ``owner`` is the one it follows; return whether it did."""
        with self._lock:
            if owner != self.owner or not self.armed:
                return False
            self.armed = False
            self._pending = False
            LOG.info("released by %s (it stopped the robot itself)", owner)
            return True

    def status(self):
        """Return the guard's state and counters as a dict."""
        with self._lock:
            since = None if self.last_beat is None else self._clock() - self.last_beat
            return {
                "armed": self.armed,
                "owner": self.owner,
                "since_last_s": since,
                "beats": self.beats,
                "stops": self.stops,
                "failed_stops": self.failed_stops,
                "lapse_s": self.lapse_s,
                "pending": self._pending,
            }

    def check(self):
        """Fire when a lapse began; retry a failed stop. Returns True when it called stop."""
        now = self._clock()
        with self._lock:
            if self.armed and self.last_beat is not None and now - self.last_beat > self.lapse_s:
                self.armed = False
                self._pending = True
                self._next_retry = now
                LOG.warning(
                    "no heartbeat from %s for %.3f s: stopping NAO (ALMotion.stopMove)",
                    self.owner,
                    now - self.last_beat,
                )
            if not self._pending or now < self._next_retry:
                return False
        try:
            self._stop()
        except Exception as exc:  # NAOqi unreachable or busy: try again shortly
            with self._lock:
                self.failed_stops += 1
                self._next_retry = self._clock() + RETRY_STOP_S
            LOG.error("ALMotion.stopMove failed (%s); retrying every %.1f s", exc, RETRY_STOP_S)
            return True
        with self._lock:
            self._pending = False
            self.stops += 1
            n = self.stops
        LOG.warning("NAO stopped (stop %d)", n)
        return True


class GuardService(object):
    """What is registered on NAOqi as ``BipedteleGuard``."""

    def __init__(self, guard):
        self._guard = guard

    def version(self):
        """Return the guard's version."""
        return VERSION

    def heartbeat(self, owner):
        """Take a heartbeat from ``owner``; return the lapse [s]."""
        return float(self._guard.heartbeat(str(owner)))

    def release(self, owner):
        """Disarm the guard for ``owner``; return whether it did."""
        return bool(self._guard.release(str(owner)))

    def status(self):
        """Return the guard's state and counters as JSON."""
        return json.dumps(self._guard.status(), sort_keys=True)


def _multithreaded(cls):
    """Let qi call the service's methods concurrently (where this qi can)."""
    try:
        import qi
    except ImportError:
        return cls
    deco = getattr(qi, "multiThreaded", None)
    return deco()(cls) if deco is not None else cls


class _Authenticator(object):
    """NAOqi >= 2.9 user/password for tcps:// (libqi's client authenticator)."""

    def __init__(self, user, token):
        self._data = {"user": user, "token": token}

    def initialAuthData(self):
        return dict(self._data)

    def _processAuth(self, data):
        return {}


class _AuthenticatorFactory(object):
    def __init__(self, user, token):
        self.user = user
        self._token = token

    def newAuthenticator(self):
        return _Authenticator(self.user, self._token)

    def authVersionMajor(self):
        return 1

    def authVersionMinor(self):
        return 0


def _call(proxy, method, timeout_s, *args):
    """``proxy.method(*args)`` waiting at most ``timeout_s`` (where this qi can)."""
    try:
        fut = getattr(proxy, method)(*args, _async=True)
    except TypeError:  # an old qi without _async
        return getattr(proxy, method)(*args)
    return fut.value(int(timeout_s * 1000))


def _read_password(path):
    if not path:
        return ""
    with open(path) as fh:
        line = fh.readline()
    return line.strip()


class Runner(object):
    """Connects to NAOqi, registers the service, watches; reconnects if NAOqi goes away."""

    def __init__(self, url, lapse_s, user="", password=""):
        self.url = url
        self.user = user
        self._password = password
        self.stopping = threading.Event()
        self._session = None
        self._motion = None
        self._lock = threading.Lock()
        self.guard = Guard(self._stop_robot, lapse_s)
        self.service = _multithreaded(GuardService)(self.guard)

    def _stop_robot(self):
        with self._lock:
            session = self._session
            motion = self._motion
        if session is None:
            raise RuntimeError("not connected to NAOqi")
        if motion is None:
            motion = _call(session, "service", 1.0, "ALMotion")
            with self._lock:
                self._motion = motion
        _call(motion, "stopMove", 1.0)

    def _connect(self):
        import qi

        session = qi.Session()
        if self.user or self._password:
            session.setClientAuthenticatorFactory(_AuthenticatorFactory(self.user, self._password))
        try:
            fut = session.connect(self.url, _async=True)
            fut.value(5000)
        except TypeError:
            session.connect(self.url)
        return session

    def _watch(self):
        while not self.stopping.is_set():
            self.guard.check()
            self.stopping.wait(CHECK_PERIOD_S)

    def run(self):
        """Serve until :attr:`stopping` is set. Returns an exit code."""
        watcher = threading.Thread(target=self._watch, name="guard-watch")
        watcher.daemon = True
        watcher.start()
        told = False
        while not self.stopping.is_set():
            try:
                session = self._connect()
            except RuntimeError as exc:
                if not told:
                    LOG.error("cannot reach NAOqi at %s (%s); retrying every %.0f s", self.url, exc, RECONNECT_S)
                    told = True
                self.stopping.wait(RECONNECT_S)
                continue
            told = False
            try:
                sid = session.registerService(SERVICE, self.service)
            except RuntimeError as exc:
                LOG.error("cannot register %s on %s: %s (is another guard running?)", SERVICE, self.url, exc)
                _close(session)
                return 3
            with self._lock:
                self._session, self._motion = session, None
            LOG.info(
                "%s registered on %s (%s, lapse %.2f s): waiting for heartbeats",
                SERVICE,
                self.url,
                VERSION,
                self.guard.lapse_s,
            )
            while not self.stopping.is_set() and _connected(session):
                self.stopping.wait(0.2)
            with self._lock:
                self._session, self._motion = None, None
            if self.stopping.is_set():
                try:
                    session.unregisterService(sid)
                except RuntimeError:
                    pass
                _close(session)
                break
            LOG.error("lost NAOqi at %s; reconnecting", self.url)
            _close(session)
        LOG.info("guard stopping (%d stops in this run)", self.guard.stops)
        return 0


def _connected(session):
    try:
        return bool(session.isConnected())
    except RuntimeError:
        return False


def _close(session):
    try:
        session.close()
    except RuntimeError:
        pass


def build_parser(parser=None):
    """Return the guard's command-line options (also used by ``bipedtele nao-guard``)."""
    if parser is None:
        parser = argparse.ArgumentParser(prog="nao_guard.py", description=__doc__.splitlines()[0])
    parser.add_argument(
        "--url",
        "--naoqi-url",
        dest="url",
        default=None,
        help="NAOqi URL (default %s; tcps://HOST:9503 with --user on NAOqi >= 2.9)" % DEFAULT_URL,
    )
    parser.add_argument("--pip", default=None, help="NAOqi address (as autoload passes it)")
    parser.add_argument("--pport", type=int, default=None, help="NAOqi port (as autoload passes it)")
    parser.add_argument(
        "--lapse",
        type=float,
        default=DEFAULT_LAPSE_S,
        metavar="S",
        help="stop NAO when no heartbeat came for S seconds (default %.1f)" % DEFAULT_LAPSE_S,
    )
    parser.add_argument("--user", default="", help="user for tcps:// (NAOqi >= 2.9)")
    parser.add_argument("--password-file", default="", help="file whose first line is the password")
    parser.add_argument("--log-file", default="", help="log here too (on the robot: /home/nao/bipedtele-guard.log)")
    return parser


def check_args(args):
    """Return the URL and lapse from ``args``, or raise ValueError with one line saying what is allowed."""
    url = args.url
    if url is None:
        url = "tcp://%s:%d" % (args.pip or "127.0.0.1", args.pport or 9559) if (args.pip or args.pport) else DEFAULT_URL
    scheme = url.split("://", 1)[0]
    if "://" not in url or scheme not in ("tcp", "tcps"):
        raise ValueError("--url %r: allowed: tcp://HOST:PORT or tcps://HOST:PORT" % url)
    if not 0.05 <= args.lapse <= 10.0:
        raise ValueError("--lapse %r: allowed: 0.05 to 10 seconds" % args.lapse)
    return url, float(args.lapse)


def serve(url, lapse_s, user="", password=""):
    """Run the guard until SIGINT/SIGTERM. Returns an exit code."""
    runner = Runner(url, lapse_s, user, password)

    def on_signal(signum, frame):
        runner.stopping.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    return runner.run()


def main(argv=None):
    """Run the guard until a signal; return the exit code."""
    args = build_parser().parse_args(argv)
    handlers = [logging.StreamHandler(sys.stderr)]  # type: list[logging.Handler]
    if args.log_file:
        handlers.append(logging.FileHandler(args.log_file))
    fmt = logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s")
    for h in handlers:
        h.setFormatter(fmt)
        logging.getLogger().addHandler(h)
    logging.getLogger().setLevel(logging.INFO)
    try:
        url, lapse = check_args(args)
        password = _read_password(args.password_file)
    except (ValueError, IOError, OSError) as exc:
        sys.stderr.write("nao_guard: %s\n" % exc)
        return 2
    try:
        import qi  # noqa: F401
    except ImportError:
        sys.stderr.write("nao_guard: the qi module is missing (on NAO it is there; elsewhere: pip install qi)\n")
        return 2
    LOG.info("bipedtele NAO guard (pid %d, Python %s)", os.getpid(), sys.version.split()[0])
    return serve(url, lapse, args.user, password)


if __name__ == "__main__":
    sys.exit(main())
