"""The router's access control: who may publish and subscribe what (deny by default).

Roles (``[network]`` on the router; see docs/network.md):

- users in ``publishers_allowed`` are **leaders**: they may put on
  ``bipedtele/<id>/{cmd,clock,status}`` and declare the liveliness token
  ``bipedtele/<id>/presence/leader/<zid>``, and receive feedback, video, status, clock and
  presence;
- users in ``followers_allowed`` are **followers**: they may put on
  ``bipedtele/<id>/{feedback,video,status,clock}`` and declare
  ``.../presence/follower/<zid>``, and receive cmd, clock, status and presence;
- users in ``observers_allowed`` are **observers**: they receive video, status and
  presence, declare ``.../presence/observer/<zid>``, and put nothing (``bipedtele status``);
- the routers of other sites, by the common name of their TLS certificate
  (``routers_allowed``, ``router-<site>``; a router that connected to this one also logs
  in, but the one this router connected to shows only its certificate): everything under
  ``bipedtele/**`` both ways. Each site's router applies its own clients' roles; the
  robots' message keys keep a site's router from forging for another site's robots;
- every other session (another user of ``credentials_file``, or one matching no
  subject) may do nothing: Zenoh's ``default_permission`` is ``deny``. That includes a
  session opened over the router's UDP listener (``links = "split"``): the roles hold
  only for sessions opened on a stream link (TLS, where mutual TLS asks for the
  certificate; :func:`stream_protocols`), so a password alone over UDP gets nothing.

Zenoh checks a message's key expression against a rule with "the rule's key expression
*includes* the message's": an allow rule on ``bipedtele/*/cmd`` does not include a put on
``bipedtele/**`` or ``**``, so wildcard puts by a leader are denied too, and nobody else
reaches the command key at all (a deny rule on the exact key, by contrast, does not
include the wildcard forms, which is how a deny-only ACL is bypassed).

Each rule lists the message kinds and flows it allows: a user's own puts and
declarations go *ingress* (client to router); what the router forwards to the user goes
*egress*, filtered by the receiving user's rules. A subscriber's declaration is also
forwarded (egress) to the publishers of its key, so the publishing role is allowed
``declare_subscriber`` egress on its own keys (that is what lets its publishers know that
someone listens). ``<id>`` is ``*`` for a user listed by name: one router may serve several
robots. A user listed as ``user@robot_id`` (repeat the entry for several robots) gets the same
rules on ``bipedtele/<robot_id>/...`` only: a leader bound to ``nao1`` cannot command ``nao2``
nor see its presence, a follower bound to ``nao1`` cannot publish as ``nao2``.
"""

from __future__ import annotations

import atexit
import shutil
import tempfile
from pathlib import Path
from typing import Any

from bipedtele.config.profile import ConfigError
from bipedtele.config.sections import NetworkConfig

__all__ = ["ROLE_KEYS", "access_control_json", "credential_users", "login_file", "stream_protocols"]

_ROOT = "bipedtele/*"

#: role -> (keys it publishes, keys it subscribes to), relative to bipedtele/<id>/
ROLE_KEYS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "leader": (("cmd", "clock", "status"), ("feedback", "video", "status", "clock")),
    "follower": (("feedback", "video", "status", "clock"), ("cmd", "clock", "status")),
    "observer": ((), ("video", "status")),
}
#: What a linked router passes (everything of a pub/sub and liveliness mesh).
_ROUTER_MESSAGES = (
    "put",
    "delete",
    "declare_subscriber",
    "liveliness_token",
    "declare_liveliness_subscriber",
    "liveliness_query",
    "query",
    "reply",
    "declare_queryable",
)
#: role -> its ``[network]`` list
ROLE_LIST = {"leader": "publishers_allowed", "follower": "followers_allowed", "observer": "observers_allowed"}


def credential_users(path: str) -> list[str]:
    """Return the user names of a router credentials file (``user:password`` lines).

    Raises
    ------
    ConfigError
        The file cannot be read or a line is not ``user:password``.
    """
    try:
        lines = Path(path).read_text(encoding="utf-8").splitlines()
    except OSError as exc:
        raise ConfigError(
            f"network.credentials_file = {path!r}: cannot read ({exc.strerror}); allowed: a file of user:password lines"
        ) from None
    users = []
    for i, line in enumerate(lines, 1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        user, sep, pwd = line.partition(":")
        if not sep or not user or not pwd:
            raise ConfigError(f"network.credentials_file = {path!r}: line {i} is not user:password")
        users.append(user.strip())
    return users


def login_file(net: NetworkConfig) -> str:
    """Return the credentials file the router's Zenoh reads: ``credentials_file`` without the ``revoked`` people.

    Without ``revoked``: ``credentials_file`` itself. Otherwise a private copy (mode 0600
    in a 0700 folder, removed when the process exits) without their lines, so their
    login is refused before any session exists.
    """
    path = net.credentials_file
    gone = set(net.revoked)
    if not gone or not path:
        return path
    credential_users(path)  # the same checks and errors as the original
    lines = Path(path).read_text(encoding="utf-8").splitlines()
    kept = [ln for ln in lines if ln.partition(":")[0].strip() not in gone or ln.lstrip().startswith("#")]
    folder = Path(tempfile.mkdtemp(prefix="bipedtele-logins-"))
    atexit.register(shutil.rmtree, folder, True)
    copy = folder / "credentials.txt"
    copy.touch(mode=0o600)
    copy.write_text("".join(f"{ln}\n" for ln in kept), encoding="utf-8")
    return str(copy)


def _rules(role: str, robots: tuple[str, ...], tag: str) -> list[dict[str, Any]]:
    """Return the allow rules of ``role`` on the keys of ``robots`` (``("*",)``: every robot), ids prefixed ``tag``."""
    pub, sub = ROLE_KEYS[role]
    roots = [f"bipedtele/{r}" for r in robots]
    pub_keys = [f"{root}/{k}" for root in roots for k in pub]
    sub_keys = [f"{root}/{k}" for root in roots for k in sub]
    presence_all = [f"{root}/presence/*/*" for root in roots]

    def rule(name: str, flows: list[str], messages: list[str], keys: list[str]) -> dict[str, Any]:
        return {
            "id": f"{tag}_{name}",
            "permission": "allow",
            "flows": flows,
            "messages": messages,
            "key_exprs": keys,
        }

    publishing = [
        rule("put", ["ingress"], ["put"], pub_keys),
        rule("matching", ["egress"], ["declare_subscriber"], pub_keys),
    ]
    return [
        *(publishing if pub_keys else []),
        rule("subscribe", ["ingress"], ["declare_subscriber"], sub_keys),
        rule("receive", ["egress"], ["put"], sub_keys),
        rule("token", ["ingress"], ["liveliness_token"], [f"{root}/presence/{role}/*" for root in roots]),
        rule("watch", ["ingress"], ["declare_liveliness_subscriber", "liveliness_query"], presence_all),
        rule("presence", ["egress"], ["liveliness_token"], presence_all),
    ]


def _bindings(entries: list[str]) -> dict[str, tuple[str, ...]]:
    """User -> the robot ids it is bound to (``("*",)``: every robot), from ``user``/``user@robot`` entries."""
    found: dict[str, set[str]] = {}
    for entry in entries:
        user, at, robot = entry.partition("@")
        found.setdefault(user, set()).add(robot if at else "*")
    return {u: ("*",) if "*" in rs else tuple(sorted(rs)) for u, rs in found.items()}


def stream_protocols(listen: list[str]) -> list[str]:
    """Return the protocols of ``listen`` a session must open on to hold a role (all but ``udp``).

    Zenoh has no TLS on UDP: a session opened over the router's UDP listener (``links =
    "split"``) shows a password and never a certificate. Zenoh gives a session its ACL
    subject from the link that opened it, and a client of the split layouts opens on its
    TLS status link first (:func:`bipedtele.link.linklayout.client_endpoints`; later links join
    only by proving the session's own multi-link key), so the roles are given to sessions
    opened on these protocols only. Empty (only UDP listeners): no restriction.
    """
    return sorted({ep.partition("/")[0] for ep in listen} - {"udp"})


def _role_entries(
    roles: dict[str, dict[str, tuple[str, ...]]], on_link: dict[str, Any], *, per_user: bool
) -> tuple[list[dict[str, Any]], list[dict[str, Any]], list[dict[str, Any]]]:
    """Return the rules, subjects and policies of the roles (users bound to robots).

    ``per_user``: one subject per user that also asks for a certificate named after the
    user (``tls_user_certs``): a person's certificate with another person's password
    matches no subject.
    """
    rules: list[dict[str, Any]] = []
    subjects: list[dict[str, Any]] = []
    policies: list[dict[str, Any]] = []
    for role, bound in roles.items():
        groups: dict[tuple[str, ...], list[str]] = {}
        for user, robots in bound.items():
            groups.setdefault(robots, []).append(user)
        for i, (robots, names) in enumerate(sorted(groups.items())):
            tag = role if robots == ("*",) and len(groups) == 1 else f"{role}{i}"
            role_rules = _rules(role, robots, tag)
            rules += role_rules
            if per_user:
                mine = [
                    {"id": f"{tag}s{j}", "usernames": [n], "cert_common_names": [n], **on_link}
                    for j, n in enumerate(names)
                ]
            else:
                mine = [{"id": f"{tag}s", "usernames": names, **on_link}]
            subjects += mine
            policies.append(
                {"id": f"{tag}_role", "rules": [r["id"] for r in role_rules], "subjects": [m["id"] for m in mine]}
            )
    return rules, subjects, policies


def access_control_json(net: NetworkConfig, listen: list[str] | None = None) -> dict[str, Any] | None:
    """Return the Zenoh ``access_control`` section for a router, or None if no role is set.

    When ``publishers_allowed`` or ``followers_allowed`` is set, the ACL is deny by
    default with the per-role allow rules of this module's docstring. Users must
    authenticate (user/password) for roles to mean anything, so a credentials file naming
    every user of the lists is required. A role holds only for sessions opened on a
    stream link (:func:`stream_protocols` of ``listen``, default ``net.listen``): a session
    over the UDP listener alone (a password without the certificate of mutual TLS) matches
    no subject and may do nothing. With ``tls_user_certs`` a role also asks for the
    certificate named after its user; the people of ``revoked`` get no role (and
    :func:`login_file` leaves them out of the logins).

    Raises
    ------
    ConfigError
        No ``credentials_file``, an unreadable one, or a role user it does not name.
    """
    roles = {role: _bindings(list(getattr(net, key))) for role, key in ROLE_LIST.items()}
    if not (roles["leader"] or roles["follower"]):
        if roles["observer"]:
            raise ConfigError(
                "network.observers_allowed: set without publishers_allowed/followers_allowed (nobody could "
                "drive); allowed: observers with the other two roles, or all three empty"
            )
        return None
    if not net.credentials_file:
        raise ConfigError(
            "network.publishers_allowed/followers_allowed: need network.credentials_file (users must "
            "authenticate); allowed: set credentials_file, or leave both lists empty"
        )
    users = credential_users(net.credentials_file)
    for role, key in ROLE_LIST.items():
        unknown = [u for u in roles[role] if u not in users]
        if unknown:
            raise ConfigError(
                f"network.{key} = {unknown[0]!r}: not a user of {net.credentials_file}; allowed: {', '.join(users)}"
            )
    protocols = stream_protocols(list(net.listen if listen is None else listen))
    gone = set(net.revoked)
    kept = {role: {u: r for u, r in bound.items() if u not in gone} for role, bound in roles.items()}
    rules, subjects, policies = _role_entries(
        kept, {"link_protocols": protocols} if protocols else {}, per_user=net.tls_user_certs
    )
    if net.routers_allowed:
        rules.append(
            {
                "id": "routers_all",
                "permission": "allow",
                "flows": ["ingress", "egress"],
                "messages": list(_ROUTER_MESSAGES),
                "key_exprs": ["bipedtele/**"],
            }
        )
        subjects.append({"id": "routers", "cert_common_names": list(net.routers_allowed)})
        policies.append({"id": "routers_role", "rules": ["routers_all"], "subjects": ["routers"]})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }
