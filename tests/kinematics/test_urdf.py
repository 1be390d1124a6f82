"""URDF -> DH description: UR10 URDFs written here agree with the shipped ur10.toml."""

import numpy as np
import pinocchio as pin
import pytest
from scipy.spatial.transform import Rotation

from kinematics.description import load_description
from kinematics.errors import DescriptionError
from kinematics.frames import fit_frames
from kinematics.model import RobotModel, dh_fixed
from kinematics.transforms import xyz_rpy_from_transform
from kinematics.urdf import description_from_urdf

UR10 = load_description("ur10")


def vec(values) -> str:
    return " ".join(repr(float(v)) for v in values)


def link(name: str, mass: float = 0.0, com=(0.0, 0.0, 0.0)) -> str:
    inertial = (
        f'<inertial><mass value="{mass!r}"/><origin xyz="{vec(com)}"/>'
        '<inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>'
        if mass > 0
        else ""
    )
    return f'<link name="{name}">{inertial}</link>'


def joint(name, parent, child, xyz, rpy, axis="0 0 1", kind="revolute") -> str:
    limit = '<limit lower="-6.283185" upper="6.283185" effort="300" velocity="2"/>'
    return (
        f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
        f'<origin xyz="{vec(xyz)}" rpy="{vec(rpy)}"/>'
        + (f'<axis xyz="{axis}"/>{limit}' if kind != "fixed" else "")
        + "</joint>"
    )


def dh_urdf() -> str:
    """A UR10 whose link frames are the DH frames of ur10.toml, masses included."""
    parts = [link("base_link")]
    placement = np.eye(4)
    for i, j in enumerate(UR10.joints, start=1):
        fixed = dh_fixed(j)
        com = fixed[:3, :3] @ np.asarray(j.com_m) + fixed[:3, 3]  # in the joint's own frame
        xyz, rpy = xyz_rpy_from_transform(placement)
        parent = "base_link" if i == 1 else f"link{i - 1}"
        parts += [link(f"link{i}", j.mass_kg, com), joint(f"j{i}", parent, f"link{i}", xyz, rpy)]
        placement = fixed
    xyz, rpy = xyz_rpy_from_transform(placement)
    parts += [link("tool0"), joint("flange", "link6", "tool0", xyz, rpy, kind="fixed")]
    return '<robot name="ur10_dh">' + "".join(parts) + "</robot>"


def ros_urdf() -> str:
    """The ROS-Industrial ur_description layout of a UR10 (y-axis joints, shoulder offsets)."""
    h = np.pi / 2
    spec = [
        ("shoulder_pan_joint", "base_link", "shoulder_link", (0, 0, 0.1273), (0, 0, 0), "0 0 1"),
        ("shoulder_lift_joint", "shoulder_link", "upper_arm_link", (0, 0.220941, 0), (0, h, 0),
         "0 1 0"),
        ("elbow_joint", "upper_arm_link", "forearm_link", (0, -0.1719, 0.612), (0, 0, 0), "0 1 0"),
        ("wrist_1_joint", "forearm_link", "wrist_1_link", (0, 0, 0.5723), (0, h, 0), "0 1 0"),
        ("wrist_2_joint", "wrist_1_link", "wrist_2_link", (0, 0.1149, 0), (0, 0, 0), "0 0 1"),
        ("wrist_3_joint", "wrist_2_link", "wrist_3_link", (0, 0, 0.1157), (0, 0, 0), "0 1 0"),
    ]  # fmt: skip
    parts = [link("base_link")] + [link(s[2]) for s in spec]
    parts += [joint(*s) for s in spec]
    parts += [
        link("tool0"),
        joint("t", "wrist_3_link", "tool0", (0, 0.0922, 0), (-h, 0, 0), "", "fixed"),
    ]
    return '<robot name="ur10_ros">' + "".join(parts) + "</robot>"


@pytest.fixture
def write(tmp_path):
    def _write(text: str, name: str = "robot.urdf"):
        path = tmp_path / name
        path.write_text(text)
        return path

    return _write


def random_q(n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-np.pi, np.pi, (n, 6))


def test_dh_layout_urdf_matches_ur10_toml(write):
    desc = description_from_urdf(write(dh_urdf()), "tool0")
    q = random_q(2000)
    np.testing.assert_allclose(RobotModel(desc).fk(q), RobotModel(UR10).fk(q), atol=1e-9)
    for ours, ref in zip(desc.joints, UR10.joints, strict=True):
        assert ours.mass_kg == pytest.approx(ref.mass_kg)
    tau = RobotModel(desc).gravity_torque(q[:50])
    np.testing.assert_allclose(tau, RobotModel(UR10).gravity_torque(q[:50]), atol=1e-9)


def test_continuous_joint(write):
    text = dh_urdf().replace('name="j6" type="revolute"', 'name="j6" type="continuous"')
    desc = description_from_urdf(write(text), "tool0")
    assert (desc.joints[5].lower_deg, desc.joints[5].upper_deg) == (-360.0, 360.0)
    q = random_q(200, seed=4)
    np.testing.assert_allclose(RobotModel(desc).fk(q), RobotModel(UR10).fk(q), atol=1e-9)


def test_gravity_matches_pinocchio_on_the_urdf(write):
    path = write(dh_urdf())
    desc = description_from_urdf(path, "tool0")
    urdf_model = pin.buildModelFromUrdf(str(path))
    data = urdf_model.createData()
    q = random_q(20, seed=1)
    ref = np.array([pin.computeGeneralizedGravity(urdf_model, data, qk) for qk in q])
    np.testing.assert_allclose(RobotModel(desc).gravity_torque(q), ref, atol=1e-9)


def test_ros_layout_urdf_equals_dh_up_to_constant_frames(write):
    desc = description_from_urdf(write(ros_urdf()), "tool0", name="ur10_ros")
    assert desc.name == "ur10_ros" and desc.n_joints == 6
    q = random_q(500, seed=2)
    ros = RobotModel(desc).fk(q)
    dh = RobotModel(UR10).fk(q, frame="flange")
    # Same joint angles, same robot: only the base and flange frames may differ.
    fit = fit_frames(ros, dh)
    assert fit.summary().max_mm < 1e-6 and fit.summary().max_arcmin < 1e-5
    base = Rotation.from_matrix(fit.T_W_0[:3, :3]).as_rotvec()
    np.testing.assert_allclose(np.abs(base), [0, 0, np.pi], atol=1e-9)  # base_link = Rz(180) DH
    np.testing.assert_allclose(fit.T_W_0[:3, 3], 0.0, atol=1e-9)
    np.testing.assert_allclose(fit.T_6_S[:3, 3], 0.0, atol=1e-9)


@pytest.mark.parametrize(
    "text, tip, match",
    [
        (None, "tool0", "URDF file not found"),
        ("<robot name='x'><link name='a'/>", "a", "unreadable URDF"),
        ("dh", "nope", "no link named 'nope'"),
        ("dh", "base_link", "no joints between the root and 'base_link'"),
    ],
)
def test_bad_urdf(write, tmp_path, text, tip, match):
    path = tmp_path / "missing.urdf" if text is None else write(dh_urdf() if text == "dh" else text)
    with pytest.raises(DescriptionError, match=match):
        description_from_urdf(path, tip)


def test_prismatic_and_tilted_first_joint_are_refused(write):
    prismatic = dh_urdf().replace('name="j3" type="revolute"', 'name="j3" type="prismatic"')
    with pytest.raises(DescriptionError, match="joint 'j3' is JointModelPZ, expected a revolute"):
        description_from_urdf(write(prismatic), "tool0")
    tilted = ros_urdf().replace('<axis xyz="0 0 1"/>', '<axis xyz="1 0 0"/>', 1)
    with pytest.raises(DescriptionError, match="joint 1 .* must turn about the root's \\+z axis"):
        description_from_urdf(write(tilted), "tool0")


def test_load_description_reads_urdf_directly_and_through_toml(write, tmp_path):
    urdf = write(dh_urdf())
    q = random_q(100, seed=7)
    direct = load_description(urdf)
    np.testing.assert_allclose(RobotModel(direct).fk(q), RobotModel(UR10).fk(q), atol=1e-9)
    toml = tmp_path / "cell_robot.toml"
    toml.write_text(
        'name = "ur10_cell"\nurdf = "robot.urdf"\ntip_link = "tool0"\n'
        "[sensors]\ntemperature_max_c = 45.0\n"
    )
    via_toml = load_description(toml)
    assert via_toml.name == "ur10_cell" and via_toml.sensors.temperature_max_c == 45.0
    np.testing.assert_allclose(RobotModel(via_toml).fk(q), RobotModel(UR10).fk(q), atol=1e-9)
