"""The MuJoCo model agrees with the robot description: names, ranges, kinematics and camera intrinsics."""

from __future__ import annotations

import math

import cv2
import mujoco
import numpy as np
import pytest

from robot_models import forward_kinematics, load_qtrobot
from robot_models.mjcf import FACE_TEXTURE, HEAD_CAMERA, build_qtrobot_mjcf, packaged_mjcf_path

MODEL = load_qtrobot()


@pytest.fixture(scope="module")
def mj():
    return mujoco.MjModel.from_xml_string(build_qtrobot_mjcf(MODEL))


def test_checked_in_xml_is_the_generated_one():
    assert packaged_mjcf_path().read_text(encoding="utf-8") == build_qtrobot_mjcf(MODEL), (
        "robot_models/mjcf/qtrobot.xml is stale: regenerate it with `python -m robot_models.mjcf`")


def test_joints_and_actuators_match_the_yaml(mj):
    assert mj.njnt == mj.nu == len(MODEL.joints)
    for i, joint in enumerate(MODEL.joints):
        jid = mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_JOINT, joint.name)
        np.testing.assert_allclose(np.degrees(mj.jnt_range[jid]), [joint.lower, joint.upper], atol=1e-9)
        assert mujoco.mj_id2name(mj, mujoco.mjtObj.mjOBJ_ACTUATOR, i) == joint.name
        assert mj.actuator_trnid[i, 0] == jid
        np.testing.assert_allclose(np.degrees(mj.actuator_ctrlrange[i]), [joint.lower, joint.upper], atol=1e-9)


def test_mujoco_kinematics_equal_the_urdf_chain(mj):
    data = mujoco.MjData(mj)
    rng = np.random.default_rng(7)
    for _ in range(20):
        angles = {j.name: float(rng.uniform(j.lower, j.upper)) for j in MODEL.joints}
        for j in MODEL.joints:
            jid = mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_JOINT, j.name)
            data.qpos[mj.jnt_qposadr[jid]] = math.radians(angles[j.name])
        mujoco.mj_kinematics(mj, data)
        frames = forward_kinematics(MODEL, angles)
        for site in ("camera", "right_hand", "left_hand"):
            sid = mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_SITE, site)
            np.testing.assert_allclose(data.site_xpos[sid], frames[site][:3, 3], atol=1e-9)
            np.testing.assert_allclose(data.site_xmat[sid].reshape(3, 3), frames[site][:3, :3], atol=1e-9)


def test_face_texture_and_camera_exist(mj):
    tid = mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_TEXTURE, FACE_TEXTURE)
    assert tid >= 0 and mj.tex_width[tid] > mj.tex_height[tid] > 0
    gid = mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_GEOM, "face_screen")
    assert mj.geom_matid[gid] == mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_MATERIAL, FACE_TEXTURE)
    cid = mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_CAMERA, HEAD_CAMERA)
    assert tuple(mj.cam_resolution[cid]) == (MODEL.camera.width, MODEL.camera.height)


def test_head_camera_projects_like_the_d435_intrinsics():
    """Small white balls at known points render where the pinhole model with fx, fy, cx, cy puts them."""
    cam = MODEL.camera
    spec = mujoco.MjSpec.from_string(build_qtrobot_mjcf(MODEL))
    frames = forward_kinematics(MODEL, {})
    cam_to_base = frames["camera"]
    points_optical = [(0.0, 0.0, 1.0), (-0.3, 0.2, 1.0), (0.4, -0.25, 1.2), (0.25, 0.3, 0.8)]
    for x, y, z in points_optical:
        world = (cam_to_base @ np.array([x, y, z, 1.0]))[:3]
        spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.004, 0, 0], pos=world.tolist(),
                                rgba=[1, 1, 1, 1])
    spec.worldbody.add_light(pos=[0.5, 0, 2], dir=[0, 0, -1], type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL,
                             diffuse=[1, 1, 1], ambient=[0.6, 0.6, 0.6])
    mj = spec.compile()
    data = mujoco.MjData(mj)
    mujoco.mj_forward(mj, data)
    with mujoco.Renderer(mj, cam.height, cam.width) as renderer:
        renderer.update_scene(data, camera=HEAD_CAMERA)
        image = renderer.render()
    bright = (image.min(axis=2) > 150).astype(np.uint8)
    _, _, _, centroids = cv2.connectedComponentsWithStats(bright)
    found = centroids[1:] + 0.5  # pixel centres: pixel i covers [i, i+1)
    for x, y, z in points_optical:
        expected = np.array([cam.fx * x / z + cam.cx, cam.fy * y / z + cam.cy])
        assert np.min(np.linalg.norm(found - expected, axis=1)) < 1.0, (expected, found)
