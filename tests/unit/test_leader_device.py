"""The simulated Falcon (eq. 1) and the LeaderDevice contract checker."""

from __future__ import annotations

import math

import numpy as np
import pytest
from bipedtele.leader.check import DeviceContractError, check_device
from bipedtele.leader.device import DeviceError, DeviceNotConnectedError, make_device
from bipedtele.leader.devices.sim_falcon import SimFalcon, SimFalconParams
from bipedtele.leader.operator import Hand


def test_sim_falcon_passes_the_contract_checker():
    check_device(SimFalcon)
    check_device(lambda: make_device("sim-falcon"))


def test_checker_catches_a_device_that_does_not_clamp():
    class NoClamp(SimFalcon):
        def apply_force(self, force_n):
            self._need()
            self._f_m = np.asarray(force_n, dtype=float)
            return self._f_m.copy()

    with pytest.raises(DeviceContractError, match="apply_force"):
        check_device(NoClamp)


def test_checker_catches_a_device_that_works_unconnected():
    class Eager(SimFalcon):
        def _need(self):
            pass

    with pytest.raises(DeviceContractError, match="before connect"):
        check_device(Eager)


def test_make_device_names_the_allowed_devices():
    with pytest.raises(ValueError, match="sim-falcon"):
        make_device("no-such-device")


def test_not_connected_errors():
    dev = SimFalcon()
    with pytest.raises(DeviceNotConnectedError):
        dev.read()
    with pytest.raises(DeviceNotConnectedError):
        dev.advance(0.001)


def test_clamp_to_8_newton_and_non_finite_to_zero():
    with SimFalcon() as dev:
        assert dev.apply_force(np.array([20.0, -9.0])).tolist() == [8.0, -8.0]
        assert dev.apply_force(np.array([math.nan, -math.inf])).tolist() == [0.0, 0.0]
        assert dev.apply_force(np.array([3.0, -2.5])).tolist() == [3.0, -2.5]


def test_walls_stop_the_handle_at_the_workspace_edge():
    with SimFalcon() as dev:
        dev.apply_force(np.array([8.0, -8.0]))
        for _ in range(1000):
            dev.advance(0.001)
            s = dev.read()
            assert np.all(np.abs(s.x_m) <= 0.05)
        s = dev.read()
        assert s.x_m.tolist() == [0.05, -0.05]
        assert s.dx_m.tolist() == [0.0, 0.0]
        # Pulling back leaves the wall at once.
        dev.apply_force(np.array([-8.0, 8.0]))
        dev.advance(0.01)
        s = dev.read()
        assert s.x_m[0] < 0.05 and s.x_m[1] > -0.05


def test_no_force_no_motion_from_rest():
    with SimFalcon(x0=(0.01, -0.02)) as dev:
        for _ in range(2000):
            dev.advance(0.001)
        s = dev.read()
        assert s.x_m.tolist() == [0.01, -0.02]
        assert s.dx_m.tolist() == [0.0, 0.0]
        assert s.t == pytest.approx(2.0)


def test_force_below_coulomb_friction_does_not_move_the_handle():
    with SimFalcon(SimFalconParams(coulomb_n=0.05)) as dev:
        dev.apply_force(np.array([0.04, -0.05]))
        dev.advance(1.0)
        assert dev.read().x_m.tolist() == [0.0, 0.0]


def test_energy_never_grows_without_force():
    with SimFalcon() as dev:
        dev.apply_force(np.array([4.0, -3.0]))
        dev.advance(0.05)
        dev.apply_force(np.zeros(2))
        energy = [dev.kinetic_energy()]
        assert energy[0] > 0
        for _ in range(3000):
            dev.advance(0.001)
            energy.append(dev.kinetic_energy())
        assert np.all(np.diff(energy) <= 1e-15)
        assert energy[-1] == 0.0  # friction stops it for good


def test_constant_force_matches_the_analytic_solution():
    """m dv = (F - f_c - b v) dt from rest: v(t) = (F - f_c)/b (1 - exp(-b t / m))."""
    p = SimFalconParams(mass_kg=0.15, viscous_n_s_m=0.2, coulomb_n=0.05)
    with SimFalcon(p) as dev:
        f = 0.6
        dev.apply_force(np.array([f, -f]))
        dev.advance(0.1)
        s = dev.read()
        t = 0.1
        a = p.viscous_n_s_m / p.mass_kg
        v = (f - p.coulomb_n) / p.viscous_n_s_m * (1 - math.exp(-a * t))
        x = (f - p.coulomb_n) / p.viscous_n_s_m * (t - (1 - math.exp(-a * t)) / a)
        assert s.dx_m[0] == pytest.approx(v, rel=0.01)
        assert s.x_m[0] == pytest.approx(x, rel=0.02)
        assert s.x_m[1] == pytest.approx(-x, rel=0.02)


def test_gravity_pulls_and_g_m_compensates():
    p = SimFalconParams(gravity_n=(0.5, 0.0))
    with SimFalcon(p) as dev:
        dev.advance(0.1)
        assert dev.read().x_m[0] < -0.001
    with SimFalcon(p) as dev:
        dev.apply_force(np.array([0.5, 0.0]))  # g_m of eq. (31)
        dev.advance(0.5)
        assert dev.read().x_m.tolist() == [0.0, 0.0]


def test_advance_carries_the_remainder_so_time_does_not_drift():
    with SimFalcon() as dev:
        for _ in range(1000):
            dev.advance(0.0004)
        assert dev.read().t == pytest.approx(0.4, abs=1e-3)
        with pytest.raises(ValueError):
            dev.advance(math.nan)


def test_an_attached_hand_moves_the_handle_to_its_target():
    with SimFalcon() as dev:
        hand = Hand(stiffness_n_m=300.0, damping_n_s_m=8.0, force_max_n=15.0, tau_s=0.1)
        hand.set_target(np.array([0.02, -0.03]))
        dev.set_operator(hand)
        dev.advance(2.0)
        s = dev.read()
        # Within the Coulomb dead band f_c / k of the target.
        assert s.x_m == pytest.approx([0.02, -0.03], abs=0.05 / 300.0 + 1e-6)
        assert np.abs(dev.hand_force_n).max() <= 0.05 + 1e-9
        # An opposing force shifts the equilibrium by F / k: the operator feels it.
        dev.apply_force(np.array([-3.0, 0.0]))
        dev.advance(2.0)
        assert dev.read().x_m[0] == pytest.approx(0.02 - 3.0 / 300.0, abs=0.05 / 300.0 + 1e-6)


def test_physical_devices_refuse_an_operator_model():
    from bipedtele.leader.device import LeaderDevice

    class Physical(SimFalcon):
        set_operator = LeaderDevice.set_operator

    with pytest.raises(DeviceError, match="sim-falcon"):
        Physical().set_operator(Hand())


def test_bad_parameters_are_refused():
    with pytest.raises(ValueError, match="mass_kg"):
        SimFalconParams(mass_kg=0.0)
    with pytest.raises(ValueError, match="coulomb_n"):
        SimFalconParams(coulomb_n=-1.0)
