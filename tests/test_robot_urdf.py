"""QTrobot's URDF: generated from robot_models (names, limits, chain), importable (primitives and packaged meshes),
and its package:// resources resolve inside the shipped package only."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from robot_models import forward_kinematics, load_qtrobot
from robot_models import urdf
from robot_models.urdf import PackageResourceError, resolve_package_uri


@pytest.fixture(scope="module")
def model():
    return load_qtrobot()


@pytest.fixture(scope="module")
def root():
    return ET.fromstring(urdf.robot_description())


def _floats(text: str | None, default: str = "0 0 0") -> np.ndarray:
    return np.array([float(v) for v in (text or default).split()])


def _urdf_fk(root: ET.Element, angles_rad: dict[str, float]) -> dict[str, np.ndarray]:
    """Link frames from the URDF's own joints (origin, then rotation about the axis), the way ROS's
    robot_state_publisher chains them; written against the URDF text, not robot_models."""
    joints = {j.find("child").get("link"): j for j in root.iter("joint")}
    frames = {"base_link": np.eye(4)}

    def frame(link: str) -> np.ndarray:
        if link not in frames:
            j = joints[link]
            origin = j.find("origin")
            t = np.eye(4)
            t[:3, :3] = Rotation.from_euler("xyz", _floats(origin.get("rpy"))).as_matrix()
            t[:3, 3] = _floats(origin.get("xyz"))
            if j.get("type") == "revolute":
                rot = np.eye(4)
                rot[:3, :3] = Rotation.from_rotvec(_floats(j.find("axis").get("xyz")) *
                                                   angles_rad.get(j.get("name"), 0.0)).as_matrix()
                t = t @ rot
            frames[link] = frame(j.find("parent").get("link")) @ t
        return frames[link]

    for link in root.iter("link"):
        frame(link.get("name"))
    return frames


def test_urdf_parses_with_one_tree_rooted_at_base_link(root):
    links = {link.get("name") for link in root.iter("link")}
    children = [j.find("child").get("link") for j in root.iter("joint")]
    parents = {j.find("parent").get("link") for j in root.iter("joint")}
    assert root.tag == "robot" and root.get("name") == "QTrobot"
    assert len(children) == len(set(children)) == len(links) - 1
    assert set(children) | {"base_link"} == links and parents <= links
    materials = {m.get("name") for m in root.findall("material")}
    for visual in root.iter("visual"):
        assert visual.find("material").get("name") in materials


def test_joints_and_limits_are_robot_models_in_radians(model, root):
    revolute = {j.get("name"): j for j in root.iter("joint") if j.get("type") == "revolute"}
    assert set(revolute) == set(model.names)
    for joint in model.joints:
        limit = revolute[joint.name].find("limit")
        assert float(limit.get("lower")) == pytest.approx(math.radians(joint.lower), abs=1e-9)
        assert float(limit.get("upper")) == pytest.approx(math.radians(joint.upper), abs=1e-9)
        assert float(limit.get("velocity")) == pytest.approx(math.radians(joint.max_velocity), abs=1e-9)
        assert float(limit.get("effort")) > 0
    by_name = {el.name: el for el in model.chain}
    for j in root.iter("joint"):
        el = by_name[j.get("name") if j.get("type") == "revolute" else j.get("name").removesuffix("_joint")]
        assert j.get("type") == el.type
        assert np.allclose(_floats(j.find("origin").get("xyz")), el.xyz)
        if el.type == "revolute":
            assert np.allclose(_floats(j.find("axis").get("xyz")), el.axis)


@pytest.mark.parametrize("pose", ["zero", "home", "random0", "random1", "random2"])
def test_forward_kinematics_from_the_urdf_equals_robot_models(model, root, pose):
    if pose == "zero":
        angles = {n: 0.0 for n in model.names}
    elif pose == "home":
        angles = model.home_pose()
    else:
        rng = np.random.default_rng(int(pose[-1]))
        angles = {j.name: float(rng.uniform(j.lower, j.upper)) for j in model.joints}
    expected = forward_kinematics(model, angles)
    got = _urdf_fk(root, {n: math.radians(a) for n, a in angles.items()})
    for el in model.chain:
        assert np.allclose(got[urdf.link_name(el)], expected[el.name], atol=1e-6), f"{el.name} at {pose}"
    # and the result is the robot's shape, not two identical mistakes: the camera is about 0.6 m up
    if pose == "zero":
        assert got["camera"][2, 3] == pytest.approx(0.596, abs=0.001)


def _stl_triangles(text: str) -> np.ndarray:
    vertices = [[float(v) for v in line.split()[1:]] for line in text.splitlines() if line.strip().startswith("vertex")]
    return np.array(vertices).reshape(-1, 3, 3)


def test_every_package_uri_resolves_to_a_closed_mesh_inside_the_package(root):
    uris = sorted({m.get("filename") for m in root.iter("mesh")})
    assert uris and all(u.startswith("package://qtrobot_description/") for u in uris)
    for uri in uris:
        path = resolve_package_uri(uri)
        assert path.is_relative_to(urdf.package_dir().resolve()) and path.stat().st_size > 0
        tris = _stl_triangles(path.read_text(encoding="ascii"))
        assert len(tris) >= 12
        normals = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
        assert np.all(np.einsum("ij,ij->i", normals, tris.mean(axis=1)) > 0), f"{uri}: a face points inward"
        # closed: every edge is shared by exactly two triangles, in opposite directions
        edges: dict[tuple, int] = {}
        for tri in np.round(tris, 9):
            for a, b in ((0, 1), (1, 2), (2, 0)):
                key = (tuple(tri[a]), tuple(tri[b]))
                edges[key] = edges.get(key, 0) + 1
        assert all(n == 1 and edges.get((b, a)) == 1 for (a, b), n in edges.items()), f"{uri} is not closed"


@pytest.mark.parametrize("uri", [
    "package://qtrobot_description/../../etc/passwd",
    "package://qtrobot_description/meshes/../../../../etc/passwd",
    "package://qtrobot_description//etc/passwd",
    "package://qtrobot_description/",
    "package://qtrobot_description",
    "package://qtrobot_description/meshes\\..\\..\\x",
    "package://qtrobot_description/C:/x",
    "package://other_description/meshes/head.stl",
    "/etc/passwd",
    "file:///etc/passwd",
    "package://qtrobot_description/meshes/no_such.stl",
    "package://qtrobot_description/meshes",
])
def test_paths_outside_the_package_are_refused_with_a_clear_error(uri):
    with pytest.raises(PackageResourceError) as err:
        resolve_package_uri(uri)
    assert repr(uri) in str(err.value) or uri.split("/")[2] in str(err.value)


def test_a_symlink_out_of_the_package_is_refused(tmp_path, monkeypatch):
    package = tmp_path / "qtrobot_description"
    (package / "meshes").mkdir(parents=True)
    (package / "meshes" / "ok.stl").write_text("solid x\nendsolid x\n")
    secret = tmp_path / "secret.txt"
    secret.write_text("not for clients")
    (package / "meshes" / "link.stl").symlink_to(secret)
    (package / "escape").symlink_to(tmp_path)
    monkeypatch.setattr(urdf, "packages", lambda: {"qtrobot_description": package})
    assert resolve_package_uri("package://qtrobot_description/meshes/ok.stl") == (package / "meshes/ok.stl").resolve()
    for uri in ("package://qtrobot_description/meshes/link.stl", "package://qtrobot_description/escape/secret.txt"):
        with pytest.raises(PackageResourceError, match="outside the package"):
            resolve_package_uri(uri)


def test_checked_in_package_matches_the_generator(model):
    """robot_models/data/ros/qtrobot_description is `python -m robot_models.urdf`'s output."""
    for rel, text in urdf.package_files(model).items():
        on_disk = (urdf.package_dir() / rel).read_text(encoding="utf-8")
        assert on_disk == text, f"{rel} drifted from robot_models; run `python -m robot_models.urdf`"
    assert urdf.robot_description() == urdf.build_qtrobot_urdf(model)
