"""The leader's telemetry sample: one typed record shared by cockpit, recorder and report.

The leader loop makes one :class:`LeaderSample` right after each command it sends; the
leader program fills the prediction and follower-status fields; the operator model (the
pilot's predictor), the cockpit (JSON), the recorder (channel ``leader/state``, see
``docs/recording.md``) and the readers of a recording (``bipedtele report``, the demo's
status line) all take this one type. Its JSON Schema, with the units of every field, is
:func:`msgspec.json.schema` of the class (:func:`bipedtele.recording.schemas.leader_state_schema`).

Every field but ``t`` defaults to None, so that a recording written by an older version,
which lacks some keys, still decodes (:func:`sample_from_map`). Numbers that were not
finite (NaN, inf) are written as ``null`` in JSON and read back as None.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Annotated, Any

import msgspec

__all__ = ["LINK_STATES", "LeaderSample", "link_words", "numpy_hook", "sample_from_map", "sample_to_json"]

#: The link states the leader's sample carries (``link``), machine-readable.
LINK_STATES: tuple[str, ...] = ("waiting", "ok", "lossy", "capacity-limited", "stale", "lost", "no-follower")


def _d(text: str) -> msgspec.Meta:
    return msgspec.Meta(description=text)


class LeaderSample(msgspec.Struct, kw_only=True, omit_defaults=True):
    """The leader loop's sample, one per command sent (cockpit, recording ``leader/state``).

    Attributes
    ----------
    t : float
        Time of the sample [s, ``time.time()`` clock].
    t_device : float or None
        Time of the device reading [s, device clock].
    seq : int or None
        Sequence number of the command sent with this sample.
    ref_v, ref_w : float or None
        Commanded speed ``k_g x_m``: forward [cm/s], turn [deg/s].
    x_v, x_w : float or None
        Handle position, forward and turn axes [m].
    dx_v, dx_w : float or None
        Handle velocity [m/s].
    force_v, force_w : float or None
        Force on the handle f_m [N].
    h1_ms, h2_ms, delay_ms : float or None
        Forward and backward delay estimates and their sum [ms]; None until warm.
    alpha_m_v, alpha_m_w : float or None
        Leader damping alpha_m [N s/m].
    gain : float or None
        Link gain in use (0 to 1).
    enable : bool or None
        The operator holds the device.
    leader_state : str or None
        Leader loop state (``starting``, ``running``, ``feedback_stale``, ``stopped``).
    link : str or None
        Link state, as the leader measures it (:data:`LINK_STATES`): ``waiting``, ``ok``,
        ``lossy``, ``capacity-limited``, ``stale``, ``lost``, ``no-follower``. (Recordings
        before issue 19 hold ``waiting``, ``ok``, ``stale``, ``no follower``.)
    feedback_age_ms : float or None
        Time since the feedback in use was received [ms] (the loop's; the force fades
        after ``feedback_timeout_s``).
    blind : str or None
        Why the robot is stopped for old feedback (``no fresh feedback for N s: ...``);
        unset while it is not (:mod:`bipedtele.leader.blind`).
    blind_stops : int or None
        How many times the robot was stopped for old feedback.
    link_lost_s : float or None
        State ``lost``: time since the last feedback arrived [s].
    control_link : str or None
        The link that carries control from this leader (:func:`bipedtele.link.relink.describe_control`:
        ``udp``, ``tls``, ``tcp``, ``PROTO (shared)`` when control moved onto another link,
        ``none``); unset without a router (peer mode) or before the session opened.
    fb_age_ms : float or None
        Age of the newest feedback accepted: now minus its send time on the leader's clock [ms].
    loss_pct : float or None
        Feedback lost over the last 2 s (sequence gaps) [%].
    rx_kbps : float or None
        Payload received over the last 2 s on feedback, video and status (goodput) [kbit/s].
    tx_kbps : float or None
        What the follower says it sends (its Status counter ``tx_bps``) [kbit/s].
    capacity_limited : bool or None
        The follower says its sending is limited by the path's capacity (``capacity_limited``).
    video_fps : float or None
        Video frames received per second over the last 2 s, all cameras [1/s].
    video_quality : int or None
        JPEG quality the follower encodes with (its ``video_quality``) [1-100].
    video_bytes : int or None
        Size of the newest video frame received [bytes].
    video_width, video_height : int or None
        Image size of the newest video frame [px].
    fb_arrived : int or None
        Feedback arrived so far (accepted by the receiver).
    fb_too_old : int or None
        Feedback refused so far as older than the age bound.
    z_e_v, z_e_w, z_r_v, z_r_w, eta_v, eta_w : float or None
        From the latest feedback: equivalent speed z_e, observer estimate z_r and measured
        speed eta; forward [cm/s], turn [deg/s].
    s_r_v, s_r_w, s_e_v, s_e_w : float or None
        Follower real and equivalent damping.
    T : float or None
        Walking cycle time [s].
    eps : float or None
        Joint-servo gain [s].
    state : str or None
        Follower state from the latest feedback.
    pose_x, pose_y, pose_yaw : float or None
        Reported robot pose [m, m, rad].
    sonar_l, sonar_r : float or None
        Sonar ranges [m].
    f_v_t, f_v_n : float or None
        Fictitious force, tangential and normal.
    operator : str or None
        Operator model.
    intended_v, intended_w : float or None
        Operator's intended speed, forward [cm/s] and turn [deg/s].
    passes_done : int or None
        Pilot passes completed.
    pred_x, pred_y, pred_yaw : float or None
        Predicted present robot pose [m, m, rad].
    ahead_x, ahead_y, ahead_yaw : float or None
        Robot pose predicted h1 ahead [m, m, rad].
    ahead_dt : float or None
        How far ahead of the present that pose is [s].
    follower_present : bool or None
        The follower's presence is seen.
    watchdog, falls, collisions : int or None
        Follower counters: watchdog stops, falls, obstacle contacts.
    follower_text : str or None
        Follower status text.
    held_by : str or None
        Who holds the robot, from the follower's status (``""``: an unnamed operator or
        free; see docs/fleet.md, Hand-over).
    hand : str or None
        This leader's hand: ``drive`` (it takes and drives the robot) or ``released``
        (it gave the robot up: stops only, another operator may take it).
    me : str or None
        This leader's operator name (``[network] user``), to tell ``held_by`` apart.
    """

    t: Annotated[float, _d("time of the sample [s, time.time()]")]
    t_device: Annotated[float | None, _d("time of the device reading [s]")] = None
    seq: Annotated[int | None, _d("sequence number of the command sent with this sample")] = None
    ref_v: Annotated[float | None, _d("commanded forward speed k_g x_m [cm/s]")] = None
    ref_w: Annotated[float | None, _d("commanded turn speed k_g x_m [deg/s]")] = None
    x_v: Annotated[float | None, _d("handle position, forward axis [m]")] = None
    x_w: Annotated[float | None, _d("handle position, turn axis [m]")] = None
    dx_v: Annotated[float | None, _d("handle velocity, forward axis [m/s]")] = None
    dx_w: Annotated[float | None, _d("handle velocity, turn axis [m/s]")] = None
    force_v: Annotated[float | None, _d("force on the handle f_m, forward axis [N]")] = None
    force_w: Annotated[float | None, _d("force on the handle f_m, turn axis [N]")] = None
    h1_ms: Annotated[float | None, _d("forward delay estimate h1 [ms]")] = None
    h2_ms: Annotated[float | None, _d("backward delay estimate h2 [ms]")] = None
    delay_ms: Annotated[float | None, _d("h1 + h2 [ms]")] = None
    alpha_m_v: Annotated[float | None, _d("leader damping, forward axis [N s/m]")] = None
    alpha_m_w: Annotated[float | None, _d("leader damping, turn axis [N s/m]")] = None
    gain: Annotated[float | None, _d("link gain in use (0 to 1)")] = None
    enable: Annotated[bool | None, _d("the operator holds the device")] = None
    leader_state: Annotated[str | None, _d("leader loop state")] = None
    link: Annotated[str | None, _d("link state (waiting, ok, lossy, capacity-limited, stale, lost, no-follower)")] = (
        None
    )
    feedback_age_ms: Annotated[float | None, _d("time since the feedback in use was received [ms]")] = None
    blind: Annotated[str | None, _d("why the robot is stopped for old feedback (unset: it is not)")] = None
    blind_stops: Annotated[int | None, _d("times the robot was stopped for old feedback")] = None
    link_lost_s: Annotated[float | None, _d("state lost: time since the last feedback arrived [s]")] = None
    control_link: Annotated[str | None, _d("the link that carries control (udp, tls, tcp, PROTO (shared), none)")] = (
        None
    )
    fb_age_ms: Annotated[float | None, _d("age of the newest feedback accepted, since it was sent [ms]")] = None
    loss_pct: Annotated[float | None, _d("feedback lost over the last 2 s [%]")] = None
    rx_kbps: Annotated[float | None, _d("payload received over the last 2 s (goodput) [kbit/s]")] = None
    tx_kbps: Annotated[float | None, _d("what the follower says it sends [kbit/s]")] = None
    capacity_limited: Annotated[bool | None, _d("the follower says the path's capacity limits it")] = None
    video_fps: Annotated[float | None, _d("video frames received per second, all cameras [1/s]")] = None
    video_quality: Annotated[int | None, _d("JPEG quality the follower encodes with [1-100]")] = None
    video_bytes: Annotated[int | None, _d("size of the newest video frame [bytes]")] = None
    video_width: Annotated[int | None, _d("width of the newest video frame [px]")] = None
    video_height: Annotated[int | None, _d("height of the newest video frame [px]")] = None
    fb_arrived: Annotated[int | None, _d("feedback arrived so far (accepted by the receiver)")] = None
    fb_too_old: Annotated[int | None, _d("feedback refused so far as older than the age bound")] = None
    z_e_v: Annotated[float | None, _d("equivalent follower speed z_e, forward [cm/s]")] = None
    z_e_w: Annotated[float | None, _d("equivalent follower speed z_e, turn [deg/s]")] = None
    z_r_v: Annotated[float | None, _d("observer estimate z_r, forward [cm/s]")] = None
    z_r_w: Annotated[float | None, _d("observer estimate z_r, turn [deg/s]")] = None
    eta_v: Annotated[float | None, _d("measured forward speed v_hip [cm/s]")] = None
    eta_w: Annotated[float | None, _d("measured turn rate [deg/s]")] = None
    s_r_v: Annotated[float | None, _d("follower real damping, forward")] = None
    s_r_w: Annotated[float | None, _d("follower real damping, turn")] = None
    s_e_v: Annotated[float | None, _d("follower equivalent damping, forward")] = None
    s_e_w: Annotated[float | None, _d("follower equivalent damping, turn")] = None
    T: Annotated[float | None, _d("walking cycle time [s]")] = None
    eps: Annotated[float | None, _d("joint-servo gain [s]")] = None
    state: Annotated[str | None, _d("follower state from the latest feedback")] = None
    pose_x: Annotated[float | None, _d("reported robot x [m]")] = None
    pose_y: Annotated[float | None, _d("reported robot y [m]")] = None
    pose_yaw: Annotated[float | None, _d("reported robot yaw [rad]")] = None
    sonar_l: Annotated[float | None, _d("left sonar range [m]")] = None
    sonar_r: Annotated[float | None, _d("right sonar range [m]")] = None
    f_v_t: Annotated[float | None, _d("fictitious force, tangential")] = None
    f_v_n: Annotated[float | None, _d("fictitious force, normal")] = None
    operator: Annotated[str | None, _d("operator model")] = None
    intended_v: Annotated[float | None, _d("operator's intended forward speed [cm/s]")] = None
    intended_w: Annotated[float | None, _d("operator's intended turn speed [deg/s]")] = None
    passes_done: Annotated[int | None, _d("pilot passes completed")] = None
    pred_x: Annotated[float | None, _d("predicted present robot x [m]")] = None
    pred_y: Annotated[float | None, _d("predicted present robot y [m]")] = None
    pred_yaw: Annotated[float | None, _d("predicted present robot yaw [rad]")] = None
    ahead_x: Annotated[float | None, _d("robot x predicted h1 ahead [m]")] = None
    ahead_y: Annotated[float | None, _d("robot y predicted h1 ahead [m]")] = None
    ahead_yaw: Annotated[float | None, _d("robot yaw predicted h1 ahead [rad]")] = None
    ahead_dt: Annotated[float | None, _d("how far ahead of the present [s]")] = None
    follower_present: Annotated[bool | None, _d("the follower's presence is seen")] = None
    watchdog: Annotated[int | None, _d("follower watchdog stops")] = None
    falls: Annotated[int | None, _d("follower falls")] = None
    collisions: Annotated[int | None, _d("follower obstacle contacts")] = None
    follower_text: Annotated[str | None, _d("follower status text")] = None
    held_by: Annotated[str | None, _d("who holds the robot (follower status)")] = None
    hand: Annotated[str | None, _d("this leader's hand: drive or released")] = None
    me: Annotated[str | None, _d("this leader's operator name")] = None


def link_words(state: str | None, lost_s: float | None = None) -> str:
    """Return the link state in words for people (``link lost for 3.2 s``, ``no follower``).

    Parameters
    ----------
    state : str or None
        One of :data:`LINK_STATES` (others are returned as they are; None: ``-``).
    lost_s : float or None
        For ``lost``: how long no feedback arrived [s].
    """
    if state is None:
        return "-"
    if state == "lost":
        return "link lost" if lost_s is None or not math.isfinite(lost_s) else f"link lost for {lost_s:.1f} s"
    if state == "no-follower":
        return "no follower"
    return state


def numpy_hook(obj: Any) -> Any:
    """Return a numpy scalar or array as plain Python values (msgspec's ``enc_hook``).

    Raises
    ------
    NotImplementedError
        ``obj`` is something else (msgspec then reports it as unsupported).
    """
    tolist = getattr(obj, "tolist", None)
    if tolist is None:
        raise NotImplementedError(f"cannot encode a {type(obj).__name__}")
    return tolist()


_ENCODER = msgspec.json.Encoder(enc_hook=numpy_hook)


def sample_to_json(sample: LeaderSample) -> bytes:
    """Return the JSON object of a sample; non-finite numbers become ``null``.

    Parameters
    ----------
    sample : LeaderSample
        The sample.

    Returns
    -------
    bytes
        UTF-8 JSON; fields left at None are left out (as the keys a sample lacks),
        numpy numbers are written as plain numbers.
    """
    return _ENCODER.encode(sample)


def sample_from_map(data: Mapping[str, Any]) -> LeaderSample | None:
    """Return the sample a recorded ``leader/state`` map holds, or None if it holds none.

    Keys missing from older recordings take their None default, keys this version does
    not know are ignored.

    Parameters
    ----------
    data : Mapping
        A ``leader/state`` record's map (:func:`bipedtele.recording.recorder.read_records`).

    Returns
    -------
    LeaderSample or None
        None when the map has no time ``t`` or a value of the wrong type.
    """
    try:
        return msgspec.convert(data, LeaderSample)
    except msgspec.ValidationError:
        return None
