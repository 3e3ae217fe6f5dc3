"""Opening a ``qi`` session to NAOqi: plain ``tcp://`` or authenticated ``tcps://``.

NAOqi >= 2.9 listens on ``tcps://HOST:9503`` and asks for a user and password: libqi asks
the session's client-authenticator factory for an authenticator whose
``initialAuthData()`` returns ``{"user": ..., "token": ...}``.
"""

from __future__ import annotations

import logging
from typing import Any

from bipedtele.follower.robot import RobotError

__all__ = ["UserTokenAuthenticator", "UserTokenAuthenticatorFactory", "import_qi", "open_session"]

LOG = logging.getLogger(__name__)


def import_qi() -> Any:
    """Return the ``qi`` module, or a :class:`RobotError` saying how to install it."""
    try:
        import qi
    except ImportError:
        raise RobotError(
            "the qi package (libqi-python) is missing: pip install 'bipedtele[naoqi]' (or pip install qi)"
        ) from None
    return qi


class UserTokenAuthenticator:
    """Client side of NAOqi's user/password authentication (one per connection)."""

    def __init__(self, user: str, token: str) -> None:
        self._data = {"user": user, "token": token}

    def initialAuthData(self) -> dict[str, str]:
        """Return the first (and only) message of the exchange."""
        return dict(self._data)

    def _processAuth(self, data: Any) -> dict[str, str]:
        """Further exchange steps (NAOqi accepts or refuses after the first)."""
        return {}


class UserTokenAuthenticatorFactory:
    """What ``qi.Session.setClientAuthenticatorFactory`` takes."""

    def __init__(self, user: str, token: str) -> None:
        self.user = user
        self._token = token

    def newAuthenticator(self) -> UserTokenAuthenticator:
        """Return a fresh authenticator for one connection."""
        return UserTokenAuthenticator(self.user, self._token)

    def authVersionMajor(self) -> int:
        """Return the protocol's major version."""
        return 1

    def authVersionMinor(self) -> int:
        """Return the protocol's minor version."""
        return 0


def open_session(url: str, user: str, password: str, timeout_s: float) -> Any:
    """Return a connected ``qi.Session`` to ``url``.

    Parameters
    ----------
    url : str
        ``tcp://HOST:PORT`` or ``tcps://HOST:PORT``.
    user, password : str
        Credentials for ``tcps://`` (ignored for ``tcp://`` when empty).
    timeout_s : float
        Connect timeout [s].

    Raises
    ------
    RobotError
        The robot cannot be reached or refused the credentials; the message says which.
    """
    qi = import_qi()
    session = qi.Session()
    if user or password:
        session.setClientAuthenticatorFactory(UserTokenAuthenticatorFactory(user, password))
    elif url.startswith("tcps://"):
        LOG.warning(
            "connecting to %s without user/password: NAOqi >= 2.9 will refuse; set naoqi.user and naoqi.password_file",
            url,
        )
    try:
        fut = session.connect(url, _async=True)
        fut.value(int(timeout_s * 1000))
    except RuntimeError as exc:
        _close_quietly(session)
        text = str(exc)
        hint = ""
        if "auth" in text.lower():
            hint = " (check naoqi.user / naoqi.password_file)"
        elif url.startswith("tcp://") and ":9503" in url:
            hint = " (port 9503 is tcps://)"
        raise RobotError(f"cannot reach NAOqi at {url}: {text}{hint}; is the robot on and on this network?") from None
    return session


def _close_quietly(session: Any) -> None:
    try:
        session.close()
    except RuntimeError as exc:  # already closed / never connected
        LOG.debug("closing qi session: %s", exc)
