"""Zenoh sessions: the configuration built from ``[network]``, the endpoint checks, opening.

:func:`zenoh_config` turns the ``[network]`` section into a :class:`zenoh.Config`, reading
only the settings of the process's role (TLS files, login, credentials and ACL lists).
:func:`open_session` opens a session from it; a client first checks its endpoints
(:mod:`bipedtele.link.linkcheck`), so that one that cannot reach its router, or is refused by
it, raises :class:`~bipedtele.link.linkcheck.LinkError` saying which failure it is.

The messaging on a session (keys, publishers, presence) is in :mod:`bipedtele.link.transport`,
the receive path in :mod:`bipedtele.link.receivers`.

Examples
--------
>>> with open_session(cfg.network) as session:                        # doctest: +SKIP
...     pubs = Publishers(session, Keys(cfg.robot.id))
"""

from __future__ import annotations

import json
import logging
import re
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path
from typing import Any

import zenoh
from bipedtele.config.profile import ConfigError
from bipedtele.config.sections import NetworkConfig
from bipedtele.link.acl import access_control_json, credential_users, login_file
from bipedtele.link.linkcheck import STEP_TIMEOUT_S, LinkError, check_endpoint
from bipedtele.link.linklayout import MAX_LINKS, client_endpoints, router_listen_endpoints
from bipedtele.link.receivers import MAX_ZENOH_MESSAGE

__all__ = ["open_raw", "open_session", "zenoh_config"]

LOG = logging.getLogger("bipedtele.link.transport")  # the name these log lines always had

#: A client's session must open within this many round trips of its router...
OPEN_RTTS = 8.0
#: ...and at least this long [s] (after the endpoint checks passed).
OPEN_MIN_S = 3.0
#: Session handshakes tried before giving up, each given twice the time of the one before.
OPEN_TRIES = 2
#: A split session's link handshake is given at most this long [s] (Zenoh's own limit).
LINK_OPEN_MAX_S = 10.0
#: A refused connection (a router still starting) is retried this long [s].
REFUSED_RETRY_S = 4.0


def _read_secret(key: str, path: str) -> str:
    try:
        return Path(path).read_text(encoding="utf-8").strip()
    except OSError as exc:
        raise ConfigError(f"network.{key} = {path!r}: cannot read ({exc.strerror}); allowed: a readable file") from None


def _read_password(net: NetworkConfig) -> str:
    return _read_secret("password_file", net.password_file) if net.password_file else net.password


def _check_file(key: str, path: str) -> str:
    if path and not Path(path).is_file():
        raise ConfigError(f"network.{key} = {path!r}: no such file; allowed: a readable PEM file")
    return path


def zenoh_config(
    net: NetworkConfig,
    *,
    mode: str | None = None,
    listen: list[str] | None = None,
    connect: list[str] | None = None,
) -> zenoh.Config:
    """Build a :class:`zenoh.Config` from the ``[network]`` section.

    Each role reads only its own settings, so one profile serves all three: a router
    reads ``listen``, its TLS server certificate, ``credentials_file`` and the ACL
    lists and ignores the client login (``user``, ``password``, ``password_file``); a
    client or peer reads ``connect``, its TLS certificate and the login and ignores
    ``credentials_file``, ``publishers_allowed`` and ``followers_allowed``.
    (``message_key_file`` is read by :func:`bipedtele.link.auth.load_message_auth`, never here.)

    Parameters
    ----------
    net : NetworkConfig
        The section.
    mode, listen, connect : optional
        Override the section's mode and endpoints (e.g. from command-line flags).

    Raises
    ------
    ConfigError
        Unreadable password/credentials/PEM files of this role.
    """
    mode = mode or net.mode
    listen = list(net.listen if listen is None else listen)
    connect = list(net.connect if connect is None else connect)
    conf = zenoh.Config()
    _put_links(conf, net, mode, listen, connect)
    _put_tls(conf, net, mode)
    _put_login(conf, net, router=mode == "router", listen=listen)
    return conf


def _put(conf: zenoh.Config, key: str, value: Any) -> None:
    """Set one key of ``conf`` to ``value`` (as JSON)."""
    conf.insert_json5(key, json.dumps(value))


def _put_links(conf: zenoh.Config, net: NetworkConfig, mode: str, listen: list[str], connect: list[str]) -> None:
    """Set the mode, the endpoints, the message bounds, scouting and reconnection."""
    _put(conf, "mode", mode)
    if mode == "router":
        listen = router_listen_endpoints(listen, net.links)
    _put(conf, "connect/endpoints", client_endpoints(connect, net.links) if mode == "client" else connect)
    _put(conf, "transport/unicast/max_links", MAX_LINKS)
    # Zenoh reassembles a fragmented message before anyone sees it: bound what one message
    # may cost (the largest valid one is a video frame, MAX_VIDEO_PAYLOAD), 1 GiB by default.
    _put(conf, "transport/link/rx/max_message_size", MAX_ZENOH_MESSAGE)
    # No shared memory: Zenoh would hand every message over 3 kB (the video frames) to a
    # process on the same machine through /dev/shm, around the network path: around TLS,
    # the link layout, a router's queues and any emulated link (docs/links.md).
    _put(conf, "transport/shared_memory/enabled", False)
    if listen or mode != "client":
        # Explicit endpoints only; a peer with no listen endpoint listens nowhere rather
        # than on an ephemeral port of every interface.
        _put(conf, "listen/endpoints", listen)
    _put(conf, "scouting/multicast/enabled", bool(net.multicast_scouting))
    if not net.multicast_scouting:
        _put(conf, "scouting/gossip/enabled", mode != "client")
    _put(conf, "connect/timeout_ms", int(net.timeout_s * 1000))
    _put(conf, "connect/exit_on_failure", False)
    # Reconnection to a lost router or peer: Zenoh retries with a doubling period up to
    # 4 s by default, so a robot could stay cut off for 4 s after its router is back.
    # Retry at least every second (one small TCP connect attempt per endpoint).
    _put(conf, "connect/retry", {"period_init_ms": 250, "period_max_ms": 1000, "period_increase_factor": 2.0})


def _put_tls(conf: zenoh.Config, net: NetworkConfig, mode: str) -> None:
    """Set the TLS files of this role (checked to exist) and mutual TLS."""
    tls: dict[str, Any] = {}
    if net.tls_root_ca:
        tls["root_ca_certificate"] = _check_file("tls_root_ca", net.tls_root_ca)
    if net.tls_cert:
        cert = _check_file("tls_cert", net.tls_cert)
        key = _check_file("tls_key", net.tls_key)
        tls.update(connect_certificate=cert, connect_private_key=key)
        if mode != "client":  # a client never listens: its certificate is a client one
            tls.update(listen_certificate=cert, listen_private_key=key)
    if net.tls_mutual:
        if not net.tls_cert:
            raise ConfigError(
                "network.tls_mutual = true: needs tls_cert and tls_key; allowed: set them or tls_mutual = false"
            )
        tls["enable_mtls"] = True
    for k, v in tls.items():
        _put(conf, f"transport/link/tls/{k}", v)


def _put_login(conf: zenoh.Config, net: NetworkConfig, *, router: bool, listen: list[str]) -> None:
    """Set a client's or peer's user/password, or a router's credentials file and ACL."""
    if not router:
        password = _read_password(net)
        if net.user or password:
            if not (net.user and password):
                raise ConfigError(
                    "network.user/password: allowed: both a user and a password (or password_file), or neither"
                )
            _put(conf, "transport/auth/usrpwd/user", net.user)
            _put(conf, "transport/auth/usrpwd/password", password)
    else:
        if net.credentials_file:
            credential_users(net.credentials_file)
            _put(conf, "transport/auth/usrpwd/dictionary_file", login_file(net))
        if net.router_user or net.router_password_file:  # the login to the other sites' routers
            if not (net.router_user and net.router_password_file):
                raise ConfigError(
                    "network.router_user/router_password_file: allowed: both (this router's login to the "
                    "routers of connect), or neither"
                )
            _put(conf, "transport/auth/usrpwd/user", net.router_user)
            _put(conf, "transport/auth/usrpwd/password", _read_secret("router_password_file", net.router_password_file))
        acl = access_control_json(net, listen)
        if acl is not None:
            _put(conf, "access_control", acl)


def _zenoh_reason(exc: BaseException) -> str:
    first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    return re.sub(r"\s+at \S+\.rs:\d+\.?$", "", first)  # Zenoh's Rust source location


def _preflight(net: NetworkConfig, connect: list[str]) -> tuple[float, set[str]]:
    """Check a client's endpoints before Zenoh does.

    Returns
    -------
    rtt_s : float
        The longest round trip seen [s].
    checked : set of str
        The protocols (``tcp``, ``tls``) of the endpoints that passed a check.

    Raises
    ------
    LinkError
        When no endpoint passes: which failure each one had.
    """
    cert, key = (net.tls_cert, net.tls_key) if net.tls_mutual else ("", "")
    step = min(STEP_TIMEOUT_S, net.timeout_s)
    # a router that is starting refuses connections for a moment: retry those (only)
    retry_until = time.monotonic() + min(REFUSED_RETRY_S, net.timeout_s)
    while True:
        checks = [check_endpoint(ep, root_ca=net.tls_root_ca, cert=cert, key=key, timeout_s=step) for ep in connect]
        passed = [c for c in checks if c.ok]
        if passed or any(c.kind != "refused" for c in checks) or time.monotonic() + 0.25 > retry_until:
            break
        time.sleep(0.25)
    if not passed:
        first = checks[0].kind
        kind = first if all(c.kind == first for c in checks) else "unreachable"
        raise LinkError(kind, "; ".join(f"{c.endpoint}: {c.detail}" for c in checks))
    checked = {c.endpoint.partition("/")[0] for c in passed} & {"tcp", "tls"}
    return max(c.rtt_s for c in passed), checked


def _open_timeout_s(net: NetworkConfig, rtt_s: float, checked: set[str]) -> float:
    """How long Zenoh may take to open a client session whose links were checked [s].

    A Zenoh session needs about 4 round trips after TCP (TLS, then its own handshake);
    a router that has not accepted it after OPEN_RTTS round trips (at least OPEN_MIN_S)
    refused the login. Without TLS and without a login there is nothing to refuse (and
    a relay such as the delay proxy hides the round trip from the TCP check): the
    profile's ``timeout_s`` then applies unchanged.
    """
    if "tls" not in checked and not net.user:
        return net.timeout_s
    return min(net.timeout_s, max(OPEN_MIN_S, OPEN_RTTS * rtt_s))


def _refusal(net: NetworkConfig, checked: set[str], spent_s: float, zenoh_reason: str, links: str) -> LinkError:
    """Return the LinkError of a client whose endpoint checks passed but whose session did not open.

    Zenoh does not tell a client why its router closed a handshake, so the message says
    what was seen (TCP, TLS accepted; no session after the tries) and names both causes
    that fit: a refused login, which the router logs, or a path too slow or lossy for the
    handshake (or, for a session of ``links = "split"`` itself, its UDP link blocked).
    """
    within = f"no session in {spent_s:.1f} s"
    if not checked:  # udp, quic, ws...: not checked beforehand
        return LinkError(
            "open",
            f"cannot open the Zenoh session: {zenoh_reason} (no router answered within {spent_s:.1f} s, "
            "or it refused this client's certificate or user/password)",
        )
    if "tls" in checked:
        seen = "TCP and TLS were accepted"
    else:
        seen = "TCP was accepted, by the router or by a relay in front of it"
    slow = "or the router did not answer the handshake in time (a lossy or slow path; the router logs every refusal)"
    if links == "split":
        slow += (
            ', or UDP to the router\'s port is blocked (the control link of links = "split"; '
            'where only TCP passes, set network.links = "split-tcp")'
        )
    if net.user:
        return LinkError(
            "credentials",
            f"the router did not open a session ({seen}; {within}): user/password refused for user {net.user!r}, "
            f"{slow}; check network.user and network.password_file against the router's credentials_file",
        )
    return LinkError(
        "credentials",
        f"the router did not open a session ({seen}; {within}): it may require a user/password "
        "(network.user, network.password_file)"
        + ("" if "tls" in checked else " or TLS (a tls/ endpoint)")
        + f", {slow}",
    )


def _open_client(net: NetworkConfig, connect: list[str], conf: zenoh.Config) -> zenoh.Session:
    """Open a client session: endpoint checks, a login on one link, then the session's links.

    A split session opens its three links one after the other, each with its own handshake
    (4.5-8 s across the emulated intercontinental trace, one link 2 s), so a budget of a few
    round trips, which tells a refused login early, cannot tell it from a slow path: 4 opens
    of 14 failed at 5 % loss (``bench/internet_open.py``). So the login is tried first on one
    link (``links = "single"``: the profile's endpoints as written), in one handshake given
    what OPEN_TRIES tries would have had in all (a refused login is told as before; a try
    started again would lose what a slow one had done). Once the router has accepted it, the
    session's own links get what is left of the profile's ``timeout_s``, and if they still do
    not open the cause is the path or its UDP, not the login (``links``). In both, a link's
    handshake that does not finish within OPEN_RTTS round trips (at least OPEN_MIN_S) is
    started again: a message lost on the UDP link is never sent again, and Zenoh's own
    limit is 10 s. A session of one link, or one with nothing the router could refuse,
    opens directly.
    """
    rtt, checked = _preflight(net, connect)
    timeout = _open_timeout_s(net, rtt, checked)
    several = any(isinstance(e, dict) for e in client_endpoints(connect, net.links))
    if not several or timeout >= net.timeout_s:
        session, spent, reason = _handshakes(conf, timeout, net.timeout_s, OPEN_TRIES)
        if session is None:
            raise _refusal(net, checked, spent, reason, net.links)
        return session
    link_ms = json.dumps(int(1000 * min(LINK_OPEN_MAX_S, timeout)))
    one_link = zenoh_config(replace(net, links="single"), mode="client", connect=connect)
    one_link.insert_json5("transport/unicast/open_timeout", link_ms)
    all_tries = sum(2**k for k in range(OPEN_TRIES)) * timeout
    probe, spent, reason = _handshakes(one_link, all_tries, net.timeout_s, 1)
    if probe is None:
        raise _refusal(net, checked, spent, reason, "single")
    probe.close()
    LOG.debug("the router accepted the login on one link in %.1f s; opening the session's links", spent)
    conf.insert_json5("transport/unicast/open_timeout", link_ms)
    session, more, reason = _handshakes(conf, net.timeout_s - spent, net.timeout_s - spent, 1)
    if session is None:
        raise _links_failed(net, spent + more, reason)
    return session


def _handshakes(
    conf: zenoh.Config, first_s: float, total_s: float, tries: int
) -> tuple[zenoh.Session | None, float, str]:
    """Try to open ``conf``'s session up to ``tries`` times, the first given ``first_s`` [s], each next twice as long, ``total_s`` [s] in all.

    Returns
    -------
    session : zenoh.Session or None
        The session (None: no try opened it).
    spent_s : float
        The time the tries took [s].
    reason : str
        Zenoh's reason for the last failure ("" when opened).

    Raises
    ------
    ConfigError
        Zenoh refused the configuration (any failure other than "Unable to connect").
    """
    spent, reason = 0.0, ""
    for attempt in range(tries):
        budget = min(first_s * 2**attempt, total_s - spent)
        if budget <= 0.05:
            break
        conf.insert_json5("connect/timeout_ms", json.dumps(int(budget * 1000)))
        t0 = time.monotonic()
        try:
            return zenoh.open(conf), spent + time.monotonic() - t0, ""
        except zenoh.ZError as exc:
            spent += time.monotonic() - t0
            reason = _zenoh_reason(exc)
            if "Unable to connect" not in reason:
                raise ConfigError(f"network: cannot open the Zenoh session: {reason}") from None
            LOG.debug("no session with the router within %.1f s (try %d of %d)", budget, attempt + 1, tries)
    return None, spent, reason


def _links_failed(net: NetworkConfig, spent_s: float, zenoh_reason: str) -> LinkError:
    """Return the LinkError of a client whose login the router accepted on one link but whose session's links did not open."""
    why = "a path too slow or lossy for their handshakes within network.timeout_s"
    if net.links == "split":
        why = (
            f'UDP to the router\'s port blocked (the control link of links = "split"; where only TCP passes, '
            f'set network.links = "split-tcp"), or {why}'
        )
    return LinkError(
        "links",
        f"the router accepted the login on one link, but the session's links (links = {net.links!r}) did not "
        f"open in {spent_s:.1f} s ({zenoh_reason}): {why}",
    )


def open_raw(
    net: NetworkConfig,
    *,
    mode: str | None = None,
    listen: list[str] | None = None,
    connect: list[str] | None = None,
) -> zenoh.Session:
    """Open a Zenoh session from the ``[network]`` section; the caller closes it.

    As :func:`open_session`, without the ``with`` block (a session that may be reopened:
    :class:`bipedtele.link.relink.RelinkSession`).
    """
    mode = mode or net.mode
    connect = list(net.connect if connect is None else connect)
    conf = zenoh_config(net, mode=mode, listen=listen, connect=connect)
    client = mode == "client" and bool(connect)
    if not client:
        try:
            session = zenoh.open(conf)
        except zenoh.ZError as exc:
            raise ConfigError(f"network: cannot open the Zenoh session: {_zenoh_reason(exc)}") from None
    else:
        session = _open_client(net, connect, conf)
    LOG.debug("zenoh session %s open (mode %s)", session.zid(), mode)
    return session


@contextmanager
def open_session(
    net: NetworkConfig,
    *,
    mode: str | None = None,
    listen: list[str] | None = None,
    connect: list[str] | None = None,
) -> Iterator[zenoh.Session]:
    """Open a Zenoh session from the ``[network]`` section; close it on exit.

    Parameters are as in :func:`zenoh_config`. A client first checks its endpoints
    (:mod:`bipedtele.link.linkcheck`: name, TCP, TLS) so that a refusal says which one it is,
    then gives Zenoh a few round trips to open the session: when the links were fine
    and Zenoh still fails, the router refused the session (user/password).

    Raises
    ------
    ConfigError
        Bad files or settings, or Zenoh refused the configuration (e.g. a listen
        endpoint cannot be bound).
    LinkError
        A client cannot reach or is refused by its router: one line saying which.
    """
    session = open_raw(net, mode=mode, listen=listen, connect=connect)
    try:
        yield session
    finally:
        session.close()
