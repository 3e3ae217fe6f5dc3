"""A contract checker for any registered control scheme (in the spirit of Gymnasium's ``check_env``).

``check_scheme(name)`` loads the scheme registered as ``name`` (or takes a class) and checks what the runners
rely on (:class:`~bipedtele.control.schemes.base.Scheme`):

- the class is a :class:`Scheme` named ``name`` with a title;
- :meth:`~Scheme.damping` gives finite ``(K, 2)`` arrays at or above the configured lower
  bounds, and changes with the delay exactly when the scheme says it ``adapts``;
- every port law gives finite arrays of the input's shape for one run (``(2,)``) and for
  many (``(n, 2)``), and row ``i`` of the many-run result is the one-run result of run ``i``
  (to 1e-12): the real loops and the comparison run the same law;
- counting a port's energy for many runs at once counts each run as counting it alone;
- the leader's ``follow`` is ``r_m - F_m / k_m`` (to rounding), before and after the
  passivity controller;
- what the comparison's follower sends back (:meth:`~Scheme.feedback_signal`) is what the
  real leader reads from a Feedback message built by the real follower
  (:meth:`~Scheme.read_feedback` of ``z_e``, ``eta`` and :meth:`~Scheme.feedback_wave`);
- the message fields (:meth:`~Scheme.command_wave`, :meth:`~Scheme.feedback_wave`,
  :meth:`~Scheme.energy_sent`) are None or a finite ``[forward, turn]`` pair;
- the received-wave gain lies in ``[0, 1]``.

The first violation raises :class:`SchemeContractError` naming the check. Units as in
:mod:`~bipedtele.control.schemes.ports`; the inputs are seeded random speeds [cm/s, deg/s].
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from bipedtele.control.config import ControlConfig
from bipedtele.control.schemes import scheme_class
from bipedtele.control.schemes.base import LeaderLaw, Scheme
from bipedtele.control.schemes.ports import EnergyCounter

__all__ = ["SchemeContractError", "check_scheme"]

RUNS = 7
DT_S = 0.01


class SchemeContractError(AssertionError):
    """A scheme does not keep the :class:`Scheme` contract."""


def _expect(cond: bool, what: str) -> None:
    if not cond:
        raise SchemeContractError(what)


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(np.allclose(a, b, rtol=1e-12, atol=1e-12))


def _array(value: object, shape: tuple[int, ...], what: str) -> np.ndarray:
    _expect(isinstance(value, np.ndarray), f"{what}: returned {type(value).__name__}, expected a numpy array")
    arr = np.asarray(value)
    _expect(arr.shape == shape, f"{what}: shape {arr.shape}, expected {shape}")
    _expect(bool(np.all(np.isfinite(arr))), f"{what}: not finite")
    return arr


def _per_run(
    name: str, law: Callable[..., np.ndarray], many: tuple[np.ndarray, ...], scalars: tuple[float, ...]
) -> None:
    """Check ``law`` on ``(n, 2)`` inputs against ``law`` run by run on ``(2,)`` ones."""
    out = _array(law(*many, *scalars), (RUNS, 2), f"{name} on {RUNS} runs")
    for i in range(RUNS):
        one = _array(law(*(m[i] for m in many), *scalars), (2,), f"{name} on one run")
        _expect(_same(one, out[i]), f"{name}: run {i} alone differs from run {i} of {RUNS}")


def _fresh(other_in: np.ndarray) -> EnergyCounter:
    """Return a port that has given out nothing yet: its observer is ``other_in`` itself."""
    return EnergyCounter(np.shape(other_in))


def _check_counts(count: Callable[[EnergyCounter, int | None], None], what: str) -> None:
    """Check that counting all runs at once counts each run as counting it alone does."""
    many = EnergyCounter((RUNS, 2))
    count(many, None)
    for i in range(RUNS):
        one = EnergyCounter((2,))
        count(one, i)
        for field in ("e_in", "e_out", "min_observer"):
            got, want = getattr(one, field), getattr(many, field)[i]
            _expect(_same(got, want), f"{what}: run {i} alone counts {field} {got}, of {RUNS}: {want}")


def _check_damping(scheme: Scheme, cfg: ControlConfig) -> None:
    low, high = np.zeros(50), np.full(50, 3.0)
    for h1, h2 in ((low, low), (high, high), (np.linspace(0, 3, 50), np.linspace(3, 0, 50))):
        alpha, s_e = scheme.damping(h1, h2)
        _array(alpha, (50, 2), "damping alpha_m")
        _array(s_e, (50, 2), "damping sigma_e")
        _expect(bool(np.all(alpha >= cfg.alpha_m_min)), "damping: alpha_m below [control] alpha_m_min")
        _expect(bool(np.all(s_e >= cfg.s_e_min)), "damping: sigma_e below [control] s_e_min")
    changes = not np.allclose(scheme.damping(low, low)[0], scheme.damping(high, high)[0])
    _expect(
        changes == type(scheme).adapts, f"damping: changes with the delay: {changes}, adapts: {type(scheme).adapts}"
    )


def _pair_or_none(value: object, what: str) -> None:
    if value is not None:
        _array(np.asarray(value, dtype=float), (2,), what)


def _check_leader(scheme: Scheme, k_m: np.ndarray, rng: np.random.Generator) -> None:
    r, signal, observer = (rng.normal(0.0, 5.0, (RUNS, 2)) for _ in range(3))
    observer = np.abs(observer) * 0.05
    gain = 0.8

    def force(r_m: np.ndarray, s: np.ndarray, g: float) -> np.ndarray:
        return scheme.leader_force(r_m, s, g, k_m).force

    def follow(r_m: np.ndarray, s: np.ndarray, g: float) -> np.ndarray:
        return scheme.leader_force(r_m, s, g, k_m).followed(r_m, k_m)

    def limited(r_m: np.ndarray, s: np.ndarray, w: np.ndarray, g: float) -> np.ndarray:
        return scheme.limit_leader(scheme.leader_force(r_m, s, g, k_m), r_m, _fresh(w), w, k_m, DT_S).force

    _per_run("leader_force().force", force, (r, signal), (gain,))
    _per_run("leader_force().followed()", follow, (r, signal), (gain,))
    _per_run("limit_leader().force", limited, (r, signal, observer), (gain,))
    for law in (scheme.leader_force(r, signal, gain, k_m), _limit(scheme, r, signal, observer, gain, k_m)):
        _expect(isinstance(law, LeaderLaw), "leader_force/limit_leader: expected a LeaderLaw")
        followed = law.followed(r, k_m)
        _expect(bool(np.allclose(followed, r - law.force / k_m, rtol=1e-9, atol=1e-9)), "follow != r_m - F_m/k_m")
        wave = scheme.command_wave(r, law, k_m)
        if wave is not None:
            _array(wave, (RUNS, 2), f"command_wave on {RUNS} runs")
            for i in range(RUNS):
                one = scheme.command_wave(r[i], _row(law, i), k_m)
                _expect(one is not None and _same(np.asarray(one), wave[i]), "command_wave: run alone differs")

    law = _limit(scheme, r, signal, observer, gain, k_m)

    def count(port: EnergyCounter, i: int | None) -> None:
        if i is None:
            scheme.count_leader(port, law, r, observer, DT_S)
        else:
            scheme.count_leader(port, _row(law, i), r[i], observer[i], DT_S)

    _check_counts(count, "count_leader")


def _row(law: LeaderLaw, i: int) -> LeaderLaw:
    """Return run ``i`` of a many-run law."""
    return LeaderLaw(law.force[i], None if law.follow is None else law.follow[i], law.received[i])


def _limit(scheme: Scheme, r: np.ndarray, s: np.ndarray, w: np.ndarray, g: float, k_m: np.ndarray) -> LeaderLaw:
    return scheme.limit_leader(scheme.leader_force(r, s, g, k_m), r, _fresh(w), w, k_m, DT_S)


def _check_follower(scheme: Scheme, k_m: np.ndarray, rng: np.random.Generator) -> None:
    ref, wave, eta, z_e = (rng.normal(0.0, 5.0, (RUNS, 2)) for _ in range(4))
    observer = np.abs(rng.normal(0.0, 0.2, (RUNS, 2)))
    gain = 0.8

    def command(ref_: np.ndarray, wave_: np.ndarray, eta_: np.ndarray, w: np.ndarray, g: float) -> np.ndarray:
        c = scheme.follower_command(ref_, wave_, g, eta_, k_m)
        return scheme.limit_follower(c, eta_, _fresh(w), w, k_m, DT_S)

    def sent(z: np.ndarray, eta_: np.ndarray) -> np.ndarray:
        return scheme.feedback_signal(lambda: z, eta_, k_m)

    _per_run(
        "follower_command()", lambda a, b, c, g: scheme.follower_command(a, b, g, c, k_m), (ref, wave, eta), (gain,)
    )
    _per_run("limit_follower(follower_command())", command, (ref, wave, eta, observer), (gain,))
    _per_run("feedback_signal()", sent, (z_e, eta), ())
    c = command(ref, wave, eta, observer, gain)

    def count(port: EnergyCounter, i: int | None) -> None:
        if i is None:
            scheme.count_follower(port, c, eta, observer, k_m, DT_S)
        else:
            scheme.count_follower(port, c[i], eta[i], observer[i], k_m, DT_S)

    _check_counts(count, "count_follower")
    for i in range(RUNS):  # the real follower's message, read by the real leader, is what the comparison sends
        fb_wave = scheme.feedback_wave(eta[i], k_m)
        _pair_or_none(fb_wave, "feedback_wave")
        field = np.zeros(2) if fb_wave is None else np.asarray(fb_wave, dtype=float)
        read = _array(scheme.read_feedback(z_e[i], eta[i], field), (2,), "read_feedback")
        _expect(_same(read, sent(z_e[i], eta[i])), "read_feedback(message) differs from feedback_signal()")
    _pair_or_none(scheme.energy_sent(np.array([3.0, 1.0])), "energy_sent")


def check_scheme(scheme: str | type[Scheme], cfg: ControlConfig | None = None, seed: int = 0) -> None:
    """Check a scheme against the :class:`Scheme` contract.

    Parameters
    ----------
    scheme : str or type
        A registered name (loaded with :func:`~bipedtele.control.schemes.scheme_class`) or a
        :class:`Scheme` subclass.
    cfg : ControlConfig, optional
        Gains and bounds (default: the defaults).
    seed : int
        Seed of the random inputs.

    Raises
    ------
    SchemeContractError
        The first check that fails, named.
    """
    cfg = cfg or ControlConfig()
    cls = scheme_class(scheme) if isinstance(scheme, str) else scheme
    name = scheme if isinstance(scheme, str) else getattr(cls, "name", "?")
    _expect(isinstance(cls, type) and issubclass(cls, Scheme), f"{name}: not a Scheme")
    _expect(cls.name == name and bool(cls.title), f"{name}: its class is named {cls.name!r}, title {cls.title!r}")
    built = cls(cfg, (0.4, 0.3))
    k_m = np.asarray(cfg.k_m, dtype=float)
    rng = np.random.default_rng(seed)
    _check_damping(built, cfg)
    _check_leader(built, k_m, rng)
    _check_follower(built, k_m, rng)
    meter = built.gain_meter(0.5)
    for k in range(20):  # the delay grows: the gain falls below one
        g = meter.update(0.01 * k, 0.015 * k)
        _expect(0.0 <= g <= 1.0, f"gain_meter: gain {g} outside [0, 1]")
    gains = _array(built.received_gains(np.arange(50) - 5, 10), (50,), "received_gains")
    _expect(bool(np.all((gains >= 0.0) & (gains <= 1.0))), "received_gains: outside [0, 1]")
