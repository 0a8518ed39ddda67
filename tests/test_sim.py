"""Tests of :mod:`ptrack_gym.sim`: validation, lifetime, torque clipping and the integrator.

The integrator identity: PyBullet's multibody step is semi-implicit Euler on the joint
coordinates,

.. math::

    \\dot q_1 = \\dot q_0 + \\Delta t\\, M(q_0)^{-1} (\\tau - h(q_0, \\dot q_0)), \\qquad
    q_1 = q_0 + \\Delta t\\, \\dot q_1,

with h(q, q̇) = C(q, q̇) q̇ + g(q) the inverse dynamics at zero acceleration. Measured
on this machine the identity holds to ≤ 2e-15 of the velocity change for all three
robots, so the tests allow 1e-9 (relative): a missing damping term, a live velocity
motor, a wrong time step or an unclipped torque would each be off by orders of magnitude
more.
"""

from __future__ import annotations

import gc
from collections.abc import Iterator

import numpy as np
import pybullet as p
import pytest

from ptrack_gym.errors import InvalidConfigError, SimulationClosedError
from ptrack_gym.robots import ROBOTS, BulletModel, RobotProfile, robot_profile
from ptrack_gym.robots.two_link import TwoLinkAnalyticModel
from ptrack_gym.sim import BulletArm, BulletSim

#: Relative tolerance of the semi-implicit Euler identity (see the module docstring).
EULER_RTOL = 1e-9

ROBOT_NAMES = sorted(ROBOTS)


@pytest.fixture
def sim() -> Iterator[BulletSim]:
    """A default 1 kHz BulletSim, closed after the test."""
    with BulletSim() as s:
        yield s


@pytest.fixture(scope="module")
def specs() -> dict[str, RobotProfile]:
    """Every robot's profile."""
    return {name: robot_profile(name) for name in ROBOT_NAMES}


def _load(sim: BulletSim, spec: RobotProfile) -> BulletArm:
    """Load ``spec``'s arm into ``sim``."""
    return sim.load_arm(spec.urdf_path, spec.joint_names, spec.torque_limits_nm)


def _rel_err(actual: np.ndarray, expected: np.ndarray, scale: np.ndarray) -> float:
    """max |actual − expected| / max |scale| (∞-norms)."""
    return float(np.max(np.abs(actual - expected)) / np.max(np.abs(scale)))


# -- construction and validation ----------------------------------------------------------


@pytest.mark.parametrize("timestep_s", [0.0, -1e-3, float("nan"), float("inf")])
def test_bad_timestep_raises_value_error(timestep_s: float) -> None:
    """A time step that is not a positive finite number raises InvalidConfigError."""
    with pytest.raises(ValueError, match="timestep_s") as excinfo:
        BulletSim(timestep_s=timestep_s)
    assert isinstance(excinfo.value, InvalidConfigError)


@pytest.mark.parametrize("gravity_mps2", [float("nan"), float("inf")])
def test_non_finite_gravity_raises_value_error(gravity_mps2: float) -> None:
    """Gravity must be finite."""
    with pytest.raises(ValueError, match="gravity_mps2"):
        BulletSim(gravity_mps2=gravity_mps2)


def test_engine_parameters_are_as_configured() -> None:
    """The client's fixed time step, sub-step count and gravity are the requested ones."""
    with BulletSim(timestep_s=2e-3, gravity_mps2=9.5) as s:
        params = p.getPhysicsEngineParameters(physicsClientId=s.client_id)
        assert params["fixedTimeStep"] == 2e-3
        assert params["numSubSteps"] == 0
        gravity = [params[f"gravityAcceleration{axis}"] for axis in "XYZ"]
        assert gravity == [0.0, 0.0, -9.5]


@pytest.mark.parametrize(
    "joint_names",
    [("joint2", "joint1"), ("joint1",), ("joint1", "joint2", "tip_joint"), ("a", "b")],
)
def test_load_arm_with_wrong_joint_names_raises_value_error(
    sim: BulletSim, specs: dict[str, RobotProfile], joint_names: tuple[str, ...]
) -> None:
    """The controlled joints must be exactly the URDF's movable joints, in order."""
    spec = specs["two_link"]
    with pytest.raises(ValueError, match="movable joints") as excinfo:
        sim.load_arm(spec.urdf_path, joint_names, (1.0,) * len(joint_names))
    assert isinstance(excinfo.value, InvalidConfigError)


@pytest.mark.parametrize("limits", [(40.0,), (40.0, 20.0, 1.0), (40.0, 0.0), (-1.0, 20.0)])
def test_load_arm_with_bad_torque_limits_raises_value_error(
    sim: BulletSim, specs: dict[str, RobotProfile], limits: tuple[float, ...]
) -> None:
    """Torque limits must be n positive numbers."""
    spec = specs["two_link"]
    with pytest.raises(ValueError, match="torque_limits_nm"):
        sim.load_arm(spec.urdf_path, spec.joint_names, limits)


def test_arm_validates_vectors_and_names_non_finite_indices(
    sim: BulletSim, specs: dict[str, RobotProfile]
) -> None:
    """Vectors of the wrong length or with NaN/inf are refused before reaching PyBullet."""
    arm = _load(sim, specs["iiwa"])
    with pytest.raises(ValueError, match=r"shape \(7,\)"):
        arm.reset_state(np.zeros(6), np.zeros(7))
    q = np.zeros(7)
    q[[1, 4]] = [np.nan, np.inf]
    with pytest.raises(ValueError, match=r"non-finite entries at \[1 4\]"):
        arm.mass_matrix(q)
    with pytest.raises(ValueError, match="tau"):
        arm.apply_torque(np.full(7, np.nan))
    with pytest.raises(ValueError, match="unknown link"):
        arm.link_index("no_such_link")


# -- lifetime -----------------------------------------------------------------------------


def test_close_is_idempotent_and_disconnects(sim: BulletSim) -> None:
    """``close()`` twice is fine; afterwards the client is disconnected."""
    cid = sim.client_id
    assert sim.connected
    assert p.isConnected(physicsClientId=cid)
    sim.close()
    sim.close()
    assert not sim.connected
    assert not p.isConnected(physicsClientId=cid)


def test_context_manager_and_garbage_collection_disconnect() -> None:
    """Leaving a ``with`` block, or dropping the last reference, disconnects the client."""
    with BulletSim() as s:
        cid = s.client_id
        assert p.isConnected(physicsClientId=cid)
    assert not p.isConnected(physicsClientId=cid)
    dropped = BulletSim()
    cid = dropped.client_id
    del dropped
    gc.collect()
    assert not p.isConnected(physicsClientId=cid)


def test_closed_sim_raises_simulation_closed_error(specs: dict[str, RobotProfile]) -> None:
    """Every use of a closed BulletSim, directly or through its arm, raises."""
    s = BulletSim()
    spec = specs["two_link"]
    arm = _load(s, spec)
    s.close()
    q = np.array(spec.home_q_rad)
    uses = [
        s.step,
        lambda: _load(s, spec),
        arm.state,
        lambda: arm.reset_state(q, np.zeros(2)),
        lambda: arm.apply_torque(np.zeros(2)),
        lambda: arm.mass_matrix(q),
        lambda: arm.inverse_dynamics(q, q, q),
        lambda: arm.link_pose(spec.ee_link),
    ]
    for use in uses:
        with pytest.raises(SimulationClosedError):
            use()


def test_state_round_trips_exactly(sim: BulletSim, specs: dict[str, RobotProfile]) -> None:
    """``reset_state`` then ``state`` returns the very same numbers."""
    arm = _load(sim, specs["panda"])
    rng = np.random.default_rng(3)
    q0 = np.array(specs["panda"].home_q_rad) + rng.uniform(-0.1, 0.1, 7)
    qd0 = rng.uniform(-1.0, 1.0, 7)
    arm.reset_state(q0, qd0)
    q, qd = arm.state()
    assert np.array_equal(q, q0)
    assert np.array_equal(qd, qd0)


# -- torque clipping ----------------------------------------------------------------------


def test_huge_torque_is_clipped_to_the_limits(specs: dict[str, RobotProfile]) -> None:
    """From rest at home, τ = (1e4, −1e4) N·m moves the arm exactly as (40, −20) N·m.

    Expected from the nominal model: q̇₁ = Δt M(q₀)⁻¹ (τ_clipped − g(q₀)) (semi-implicit
    Euler from rest); the unclipped torque would predict a change ~250x larger.
    """
    spec = specs["two_link"]
    model = BulletModel(spec)
    try:
        with BulletSim() as s:
            arm = _load(s, spec)
            q0, zeros = np.array(spec.home_q_rad), np.zeros(2)
            huge = np.array([1e4, -1e4])
            clipped = np.array([40.0, -20.0])
            assert np.array_equal(arm.clip_torque(huge), clipped)

            arm.reset_state(q0, zeros)
            arm.apply_torque(huge)
            s.step()
            q1, qd1 = arm.state()

            arm.reset_state(q0, zeros)
            arm.apply_torque(clipped)
            s.step()
            q1_clipped, qd1_clipped = arm.state()

            mass, grav = model.mass_matrix(q0), model.gravity(q0)
            expected = s.timestep_s * np.linalg.solve(mass, clipped - grav)
            unclipped = s.timestep_s * np.linalg.solve(mass, huge - grav)
    finally:
        model.close()
    assert np.array_equal(qd1, qd1_clipped)
    assert np.array_equal(q1, q1_clipped)
    assert _rel_err(qd1, expected, expected) <= EULER_RTOL
    assert _rel_err(qd1, unclipped, unclipped) > 0.5


# -- the integrator -----------------------------------------------------------------------


@pytest.mark.parametrize("robot", ROBOT_NAMES)
def test_one_step_is_semi_implicit_euler(robot: str, specs: dict[str, RobotProfile]) -> None:
    """q̇₁ = q̇₀ + Δt M(q₀)⁻¹(τ − h(q₀, q̇₀)) and q₁ = q₀ + Δt q̇₁, to 1e-9 relative.

    Five random states (q within ±0.2 rad of home, |q̇| ≤ 0.5 rad/s) and torques
    uniform within the limits; M and h from the nominal BulletModel (a separate client).
    """
    spec = specs[robot]
    rng = np.random.default_rng(20240 + ROBOT_NAMES.index(robot))
    limits = np.array(spec.torque_limits_nm)
    model = BulletModel(spec)
    try:
        with BulletSim() as s:
            arm = _load(s, spec)
            dt = s.timestep_s
            for _ in range(5):
                q0 = np.array(spec.home_q_rad) + rng.uniform(-0.2, 0.2, spec.n)
                qd0 = rng.uniform(-0.5, 0.5, spec.n)
                tau = rng.uniform(-1.0, 1.0, spec.n) * limits
                arm.reset_state(q0, qd0)
                arm.apply_torque(tau)
                s.step()
                q1, qd1 = arm.state()
                # Below PyBullet's 100 rad/s clamp, else the identity cannot hold.
                assert np.max(np.abs(qd1)) < 100.0

                h = model.inverse_dynamics(q0, qd0, np.zeros(spec.n))
                qd1_expected = qd0 + dt * np.linalg.solve(model.mass_matrix(q0), tau - h)
                assert _rel_err(qd1, qd1_expected, qd1_expected - qd0) <= EULER_RTOL
                assert _rel_err(q1, q0 + dt * qd1, q1 - q0) <= EULER_RTOL
                assert _rel_err(q1, q0 + dt * qd1_expected, q1 - q0) <= EULER_RTOL
    finally:
        model.close()


def _com_position(arm: BulletArm, link: str, q: np.ndarray) -> np.ndarray:
    """World position (m) of ``link``'s centre of mass at pose ``q`` (moves the arm)."""
    arm.reset_state(q, np.zeros(arm.n))
    cid, j = arm.sim.client_id, arm.link_index(link)
    return np.array(
        p.getLinkState(arm.body_id, j, computeForwardKinematics=1, physicsClientId=cid)[0]
    )


@pytest.mark.parametrize("robot", ROBOT_NAMES)
def test_com_jacobian_is_the_centre_of_mass_velocity(
    robot: str, specs: dict[str, RobotProfile]
) -> None:
    """J(q) of every link equals central differences of the link's centre of mass in q —
    not of its frame origin, which PyBullet's Jacobian at point 0 is (0.1-0.2 m/rad off)."""
    spec = specs[robot]
    rng = np.random.default_rng(7 + ROBOT_NAMES.index(robot))
    with BulletSim() as s:
        arm = _load(s, spec)
        q = np.array(spec.home_q_rad) + rng.uniform(-0.3, 0.3, spec.n)
        eps = 1e-6
        for link in arm.link_names:
            fd = np.column_stack([
                (_com_position(arm, link, q + eps * e) - _com_position(arm, link, q - eps * e))
                / (2 * eps)
                for e in np.eye(spec.n)
            ])  # fmt: skip
            np.testing.assert_allclose(arm.com_jacobian(link, q), fd, atol=1e-7, err_msg=link)


@pytest.mark.parametrize("robot", ROBOT_NAMES)
def test_a_force_at_a_centre_of_mass_acts_as_its_jacobian_transpose(
    robot: str, specs: dict[str, RobotProfile]
) -> None:
    """One step with a world force F at a link's centre of mass (how a push is applied)
    moves the arm exactly as one step with the joint torque J(q)ᵀF (how the disturbance
    ledger and the delivered-energy sizing count it), on every link of every robot."""
    spec = specs[robot]
    rng = np.random.default_rng(11 + ROBOT_NAMES.index(robot))
    with BulletSim() as s:
        arm = _load(s, spec)
        q0 = np.array(spec.home_q_rad) + rng.uniform(-0.2, 0.2, spec.n)
        qd0 = rng.uniform(-0.5, 0.5, spec.n)
        for link in arm.link_names:
            force = rng.normal(size=3) * 30.0
            arm.reset_state(q0, qd0)
            arm.apply_torque(np.zeros(spec.n))
            s.step()
            free = arm.state()[1]
            arm.reset_state(q0, qd0)
            arm.apply_torque(np.zeros(spec.n))
            arm.apply_link_force(link, force)
            s.step()
            pushed = arm.state()[1]
            arm.reset_state(q0, qd0)
            arm.apply_torque_list((arm.com_jacobian(link, q0).T @ force).tolist())  # unclipped
            s.step()
            equivalent = arm.state()[1]
            if np.array_equal(equivalent, free):  # a link on the fixed base: J = 0
                assert np.array_equal(pushed, free), link
                continue
            assert _rel_err(pushed, equivalent, equivalent - free) <= 1e-7, link


def test_two_link_step_matches_the_closed_form_model(specs: dict[str, RobotProfile]) -> None:
    """The same identity with M and h from the textbook equations, not from PyBullet.

    An independent check that the plant is the two-link arm of the module docstring of
    :mod:`ptrack_gym.robots.two_link` (10 random states, 1 kHz).
    """
    spec = specs["two_link"]
    analytic = TwoLinkAnalyticModel()
    rng = np.random.default_rng(7)
    with BulletSim() as s:
        arm = _load(s, spec)
        dt = s.timestep_s
        for _ in range(10):
            q0 = rng.uniform(-2.5, 2.5, 2)
            qd0 = rng.uniform(-3.0, 3.0, 2)
            tau = rng.uniform(-1.0, 1.0, 2) * np.array(spec.torque_limits_nm)
            arm.reset_state(q0, qd0)
            arm.apply_torque(tau)
            s.step()
            q1, qd1 = arm.state()
            h = analytic.inverse_dynamics(q0, qd0, np.zeros(2))
            qd1_expected = qd0 + dt * np.linalg.solve(analytic.mass_matrix(q0), tau - h)
            assert _rel_err(qd1, qd1_expected, qd1_expected - qd0) <= EULER_RTOL
            assert _rel_err(q1, q0 + dt * qd1_expected, q1 - q0) <= EULER_RTOL
