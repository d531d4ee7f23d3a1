"""QTrobot's URDF (what ROS#'s importer and `/rosapi/get_param robot_description` serve), generated from the robot
description so that it cannot disagree with the kinematics, the limits or the MuJoCo model.

The URDF lives in a ROS package, `qtrobot_description`, shipped as package data (robot_models/data/ros/): its
meshes are named by `package://qtrobot_description/...` URIs, which a client fetches through the `file_server`
service and `resolve_package_uri` turns into a file inside that directory, refusing anything outside it.
Regenerate the checked-in files with `python -m robot_models.urdf`; a test fails when they drift.

Names: each revolute chain element is a URDF joint of the same name (what /joint_states carries), turning its
child link `<Joint>_link`; each fixed element (camera optical frame, hands) is a link of its own name, attached
by the joint `<name>_joint`. Angles are radians, lengths metres, velocities rad/s (URDF's units).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from importlib import resources
from pathlib import Path, PurePosixPath

import numpy as np
from scipy.spatial.transform import Rotation

from .qtrobot import ChainElement, RobotModel, load_qtrobot

PACKAGE = "qtrobot_description"
URDF_PATH = "urdf/qtrobot.urdf"
HEAD_MESH = "meshes/head.stl"
FACE_MESH = "meshes/face_screen.stl"
EFFORT_NM = 10.0  # LuxAI publishes no joint torque; URDF requires a figure for revolute limits
_SCHEME = "package://"


class PackageResourceError(ValueError):
    """A `package://` URI that names nothing this server ships, or a path outside the package."""


def _f(*values: float) -> str:
    """Lengths: micrometres are plenty."""
    return " ".join(f"{v:.6g}" if abs(v) > 1e-12 else "0" for v in values)


def _rad(*values: float) -> str:
    """Angles and limits: enough digits that degrees converted back match robot_models to 1e-9."""
    return " ".join(f"{v:.12g}" if abs(v) > 1e-15 else "0" for v in values)


def link_name(el: ChainElement) -> str:
    """The URDF link a chain element's frame belongs to."""
    return f"{el.name}_link" if el.type == "revolute" else el.name


def joint_name(el: ChainElement) -> str:
    """The URDF joint placing a chain element (the element's own name for revolute ones)."""
    return el.name if el.type == "revolute" else f"{el.name}_joint"


def _origin(parent: ET.Element, xyz, rpy=(0.0, 0.0, 0.0)) -> None:
    ET.SubElement(parent, "origin", xyz=_f(*xyz), rpy=_rad(*rpy))


def _visual(link: ET.Element, geometry: tuple[str, dict[str, str]], material: str, xyz=(0, 0, 0), rpy=(0, 0, 0),
            collision: bool = True) -> None:
    """A visual (and, for primitives, the same collision shape) on a link."""
    for tag in ("visual", "collision") if collision else ("visual",):
        el = ET.SubElement(link, tag)
        _origin(el, xyz, rpy)
        ET.SubElement(ET.SubElement(el, "geometry"), geometry[0], geometry[1])
        if tag == "visual":
            ET.SubElement(el, "material", name=material)


def _segment(length_vec, radius: float) -> tuple[tuple[str, dict[str, str]], tuple, tuple]:
    """A cylinder from the link origin to `length_vec` (URDF cylinders lie along their own z)."""
    v = np.asarray(length_vec, dtype=float)
    n = float(np.linalg.norm(v))
    rot, _ = Rotation.align_vectors([v / n], [[0.0, 0.0, 1.0]])
    return ("cylinder", {"radius": _f(radius), "length": _f(n)}), tuple(v / 2), tuple(rot.as_euler("xyz"))


def _mesh(path: str) -> tuple[str, dict[str, str]]:
    return ("mesh", {"filename": f"{_SCHEME}{PACKAGE}/{path}"})


def build_qtrobot_urdf(model: RobotModel | None = None) -> str:
    """The URDF text: the chain's origins and axes, limits in radians, primitives plus two packaged meshes."""
    model = model or load_qtrobot()
    g = model.geometry
    if g is None:
        raise ValueError("the robot model has no geometry section; load it with load_qtrobot()")
    robot = ET.Element("robot", name=model.name)
    for name, rgba in (("qt_shell", "0.93 0.93 0.9 1"), ("qt_dark", "0.15 0.15 0.17 1"),
                       ("qt_screen", "0.05 0.05 0.08 1")):
        ET.SubElement(ET.SubElement(robot, "material", name=name), "color", rgba=rgba)

    base = ET.SubElement(robot, "link", name="base_link")
    _visual(base, ("cylinder", {"radius": _f(g.torso_radius), "length": _f(g.torso_length)}), "qt_shell",
            xyz=(0, 0, g.torso_top_z - g.torso_length / 2))
    links = {"base_link": base}
    for el in model.chain:
        link = links[link_name(el)] = ET.SubElement(robot, "link", name=link_name(el))
        parent = "base_link" if el.parent == "base_link" else link_name(next(p for p in model.chain
                                                                            if p.name == el.parent))
        joint = ET.SubElement(robot, "joint", name=joint_name(el), type=el.type)
        _origin(joint, el.xyz, tuple(math.radians(a) for a in el.rpy_deg))
        ET.SubElement(joint, "parent", link=parent)
        ET.SubElement(joint, "child", link=link_name(el))
        if el.type == "revolute":
            spec = model.joint(el.name)
            ET.SubElement(joint, "axis", xyz=_f(*el.axis))
            ET.SubElement(joint, "limit", lower=_rad(math.radians(spec.lower)), upper=_rad(math.radians(spec.upper)),
                          effort=_f(EFFORT_NM), velocity=_rad(math.radians(spec.max_velocity)))
        _add_link_shapes(model, el, link)
    ET.indent(robot)
    return '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"


def _add_link_shapes(model: RobotModel, el: ChainElement, link: ET.Element) -> None:
    """The same body shapes as the MuJoCo model (robot_models.mjcf), in URDF's vocabulary."""
    g = model.geometry
    assert g is not None
    children = [c for c in model.chain if c.parent == el.name]
    if el.name == "HeadYaw":
        _visual(link, ("cylinder", {"radius": "0.03", "length": _f(children[0].xyz[2])}), "qt_dark",
                xyz=(0, 0, children[0].xyz[2] / 2))
    elif el.name == "HeadPitch":
        zc = g.head_center_above_pitch
        # URDF has no ellipsoid: the head is a packaged mesh, with a sphere of its mean radius for collisions.
        _visual(link, _mesh(HEAD_MESH), "qt_shell", xyz=(0, 0, zc), collision=False)
        coll = ET.SubElement(link, "collision")
        _origin(coll, (0, 0, zc))
        ET.SubElement(ET.SubElement(coll, "geometry"), "sphere", radius=_f(min(g.head_semi_axes)))
        _visual(link, _mesh(FACE_MESH), "qt_screen", xyz=(g.head_semi_axes[0] + g.face_thickness / 2 + 0.001, 0, zc),
                collision=False)
        camera = next(c for c in children if c.name == "camera")
        _visual(link, ("box", {"size": _f(*(2 * s for s in g.camera_box))}), "qt_dark",
                xyz=(camera.xyz[0] - g.camera_box[0], camera.xyz[1], camera.xyz[2]))
    elif el.name.endswith("ShoulderPitch"):
        shape, xyz, rpy = _segment(children[0].xyz, g.upper_arm_radius * 1.1)
        _visual(link, shape, "qt_shell", xyz=xyz, rpy=rpy)
    elif el.name.endswith("ShoulderRoll"):
        shape, xyz, rpy = _segment(children[0].xyz, g.upper_arm_radius)
        _visual(link, shape, "qt_shell", xyz=xyz, rpy=rpy)
    elif el.name.endswith("ElbowRoll"):
        hand = children[0]
        shape, xyz, rpy = _segment((hand.xyz[0], hand.xyz[1] - g.hand_radius, hand.xyz[2]), g.forearm_radius)
        _visual(link, shape, "qt_shell", xyz=xyz, rpy=rpy)
    elif el.name.endswith("_hand"):
        # the hand link's frame is rotated; a sphere does not care
        _visual(link, ("sphere", {"radius": _f(g.hand_radius)}), "qt_shell")


def _stl(name: str, triangles: np.ndarray) -> str:
    """ASCII STL of (n, 3, 3) triangles, counter-clockwise seen from outside, metres."""
    lines = [f"solid {name}"]
    for tri in triangles:
        normal = np.cross(tri[1] - tri[0], tri[2] - tri[0])
        norm = float(np.linalg.norm(normal))
        normal = normal / norm if norm > 0 else normal
        lines.append(f"  facet normal {_f(*normal)}\n    outer loop")
        lines.extend(f"      vertex {_f(*v)}" for v in tri)
        lines.append("    endloop\n  endfacet")
    lines.append(f"endsolid {name}")
    return "\n".join(lines) + "\n"


def head_mesh(model: RobotModel | None = None, rings: int = 12, segments: int = 24) -> str:
    """The head: an ellipsoid with the geometry section's semi-axes, centred on its origin."""
    model = model or load_qtrobot()
    assert model.geometry is not None
    a, b, c = model.geometry.head_semi_axes

    def point(i: int, j: int) -> np.ndarray:
        theta, phi = math.pi * i / rings, 2 * math.pi * j / segments
        return np.array([a * math.sin(theta) * math.cos(phi), b * math.sin(theta) * math.sin(phi),
                         c * math.cos(theta)])

    tris = []
    for i in range(rings):
        for j in range(segments):
            p00, p01, p10, p11 = point(i, j), point(i, j + 1), point(i + 1, j), point(i + 1, j + 1)
            if i > 0:
                tris.append((p00, p10, p01))
            if i < rings - 1:
                tris.append((p01, p10, p11))
    return _stl("qtrobot_head", np.array(tris))


def face_mesh(model: RobotModel | None = None) -> str:
    """The face screen: a thin box facing +x (forward), centred on its origin."""
    model = model or load_qtrobot()
    g = model.geometry
    assert g is not None
    hx, hy, hz = g.face_thickness / 2, g.face_width / 2, g.face_height / 2
    corners = np.array([[sx * hx, sy * hy, sz * hz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    # faces as corner indices (bit 2: x, bit 1: y, bit 0: z), counter-clockwise seen from outside
    quads = [(4, 6, 7, 5), (0, 1, 3, 2), (2, 3, 7, 6), (0, 4, 5, 1), (1, 5, 7, 3), (0, 2, 6, 4)]
    tris = [corners[[q[0], q[1], q[2]]] for q in quads] + [corners[[q[0], q[2], q[3]]] for q in quads]
    return _stl("qtrobot_face_screen", np.array(tris))


def package_files(model: RobotModel | None = None) -> dict[str, str]:
    """Path inside the package -> text, for every generated file of qtrobot_description."""
    model = model or load_qtrobot()
    return {
        "package.xml": (
            '<?xml version="1.0"?>\n<package format="2">\n'
            f"  <name>{PACKAGE}</name>\n  <version>0.1.0</version>\n"
            "  <description>QTrobot's URDF and meshes, generated by vr-teleop-server's robot_models from its robot "
            "description (python -m robot_models.urdf)</description>\n"
            '  <maintainer email="vr-teleop@example.org">vr-teleop-server</maintainer>\n'
            "  <license>MIT</license>\n  <buildtool_depend>catkin</buildtool_depend>\n</package>\n"),
        URDF_PATH: build_qtrobot_urdf(model),
        HEAD_MESH: head_mesh(model),
        FACE_MESH: face_mesh(model),
    }


def package_dir() -> Path:
    """The shipped qtrobot_description directory."""
    return Path(str(resources.files("robot_models").joinpath(f"data/ros/{PACKAGE}")))


def packages() -> dict[str, Path]:
    """ROS package name -> directory, for every package this project ships (what `package://` may name)."""
    return {PACKAGE: package_dir()}


def resolve_package_uri(uri: str) -> Path:
    """The file a `package://PKG/PATH` URI names, inside a shipped package; PackageResourceError otherwise.

    Refused: another scheme or none, an unknown package, an absolute or empty path, any `..` segment, and
    anything whose real path (after symlinks) leaves the package directory, or that is not a regular file."""
    if not isinstance(uri, str) or not uri.startswith(_SCHEME):
        raise PackageResourceError(f"{uri!r} is not a package:// URI; ask for package://{PACKAGE}/<path>, as the "
                                   "robot_description names its resources")
    package, sep, rel = uri[len(_SCHEME):].partition("/")
    roots = packages()
    if package not in roots:
        raise PackageResourceError(f"unknown package {package!r} in {uri!r}; this server ships: {', '.join(roots)}")
    path = PurePosixPath(rel)
    if not sep or not rel or path.is_absolute() or rel.startswith("\\") or ":" in rel:
        raise PackageResourceError(f"{uri!r}: the path inside the package must be relative (package://{package}/"
                                   "meshes/...)")
    if any(part == ".." for part in path.parts) or "\\" in rel:
        raise PackageResourceError(f"{uri!r}: '..' and backslashes are not allowed; name a file inside {package}")
    root = roots[package].resolve()
    target = (root / path).resolve()
    if not target.is_relative_to(root):
        raise PackageResourceError(f"{uri!r} leads outside the package {package} (a link out of it?); refused")
    if not target.is_file():
        raise PackageResourceError(f"{uri!r}: no such file in package {package}")
    return target


def robot_description() -> str:
    """The URDF text as served for the `robot_description` parameter (the checked-in file)."""
    return (package_dir() / URDF_PATH).read_text(encoding="utf-8")


def main() -> None:
    root = package_dir()
    for rel, text in package_files().items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
        print(path)


if __name__ == "__main__":
    main()
