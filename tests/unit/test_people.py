"""3-D people (sim/people.py): numpy skinning against hand-computed cases, and the baked files."""
from __future__ import annotations

import math

import numpy as np
import pytest

from cinetransfer.services.autopilot_bridge.sim import people as P
from cinetransfer.shared.messages import COCO17_NAMES

L = {n: i for i, n in enumerate(COCO17_NAMES)}
BODY_JOINTS = [L[n] for n in COCO17_NAMES if n.startswith(("left_", "right_")) and "eye" not in n and "ear" not in n]
PAIRS_LR = [(L[f"left_{n}"], L[f"right_{n}"]) for n in ("eye", "ear", "shoulder", "hip")]


def _rz(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def test_one_vertex_two_bones_by_hand() -> None:
    # bone 0 at the origin, bone 1 (its child) with its head at (1, 0, 0), turned 90 deg about z;
    # the root moved up by 1. Bone 1 maps (2, 0, 0) to its head (1, 0, 1) + Rz90 (1, 0, 0) = (1, 1, 1);
    # bone 0 maps it to (2, 0, 1). Weights 0.25 / 0.75 blend them to (1.25, 0.75, 1).
    heads = np.array([[0.0, 0, 0], [1.0, 0, 0]])
    g, p = P.forward_kinematics(heads, np.stack([np.eye(3), _rz(90)]), np.array([0.0, 0, 1]), parents=(-1, 0))
    np.testing.assert_allclose(p, [[0, 0, 1], [1, 0, 1]], atol=1e-12)
    m = P.bone_matrices(g, p, heads)
    v = P.skin_vertices(np.array([[2.0, 0, 0]], np.float32), np.array([[0, 1]]), np.array([[0.25, 0.75]]), m)
    np.testing.assert_allclose(v, [[1.25, 0.75, 1.0]], atol=1e-6)


def test_chained_rotations_compose_in_world_axes() -> None:
    # two 90-degree turns about z along a chain: the grandchild's world rotation is 180 degrees
    heads = np.array([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]])
    g, p = P.forward_kinematics(heads, np.stack([np.eye(3), _rz(90), _rz(90)]), np.zeros(3), parents=(-1, 0, 1))
    np.testing.assert_allclose(g[2], _rz(180), atol=1e-12)
    np.testing.assert_allclose(p[2], [1, 1, 0], atol=1e-12)


def test_quaternions_to_matrices() -> None:
    half = math.sqrt(0.5)
    np.testing.assert_allclose(P.quat_to_matrix(np.array([half, 0, 0, half])), _rz(90), atol=1e-12)
    np.testing.assert_allclose(P.quat_to_matrix(np.array([1.0, 0, 0, 0])), np.eye(3), atol=1e-12)


@pytest.fixture(scope="module", params=P.PEOPLE)
def person(request) -> P.Person:
    return P.load_person(request.param)


@pytest.fixture(scope="module", params=P.MOTIONS)
def motion(request) -> P.Motion:
    return P.load_motion(request.param)


def _identity() -> tuple[np.ndarray, np.ndarray]:
    return np.repeat(np.eye(3)[None], len(P.BONES), 0), np.zeros(3)


def test_rest_pose_reproduces_the_rest_mesh(person: P.Person) -> None:
    posed = person.skin(*_identity())
    np.testing.assert_allclose(posed.vertices_m, person.vertices_m, atol=1e-5)
    np.testing.assert_allclose(posed.joints_m, person.joint_moments.sum(axis=1), atol=1e-5)
    np.testing.assert_allclose(posed.root_m, person.bone_heads_m[0], atol=1e-6)


def test_rest_body_is_grounded_upright_and_facing_x(person: P.Person) -> None:
    v, j = person.vertices_m, person.skin(*_identity()).joints_m
    assert abs(v[:, 2].min()) < 1e-4
    assert abs(v[:, 2].max() - person.height_m) < 1e-4
    np.testing.assert_allclose(person.bone_heads_m[0, :2], 0.0, atol=1e-5)   # root over the origin
    ears = (j[L["left_ear"]] + j[L["right_ear"]]) / 2
    assert j[L["nose"]][0] > ears[0] + 0.05                                   # the face looks along +x
    z = [j[L[n], 2] for n in ("nose", "left_shoulder", "left_hip", "left_knee", "left_ankle")]
    assert z == sorted(z, reverse=True)


def _inside(points: np.ndarray, v: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Points inside the mesh: majority over 3 rays of the crossing-count parity (Moller-Trumbore)."""
    a, b, c = v[faces[:, 0]], v[faces[:, 1]], v[faces[:, 2]]
    e1, e2 = b - a, c - a
    votes = np.zeros(len(points), int)
    for d in np.array([[0.31, 0.52, 0.79], [-0.62, 0.27, -0.73], [0.11, -0.95, 0.29]]):
        h = np.cross(d, e2)
        det = np.einsum("fi,fi->f", e1, h)
        ok = np.abs(det) > 1e-12
        for k, o in enumerate(points):
            s = o - a
            u = np.einsum("fi,fi->f", s, h) / np.where(ok, det, 1)
            q = np.cross(s, e1)
            w = (q @ d) / np.where(ok, det, 1)
            t = np.einsum("fi,fi->f", q, e2) / np.where(ok, det, 1)
            hits = ok & (u >= 0) & (w >= 0) & (u + w <= 1) & (t > 0)
            votes[k] += int(hits.sum() % 2)
    return votes >= 2


def test_joints_inside_the_body_and_feet_on_the_ground(person: P.Person, motion: P.Motion) -> None:
    for t in np.linspace(0, motion.duration_s, 4, endpoint=False):
        posed = person.pose(motion, float(t))
        inside = _inside(posed.joints_m[BODY_JOINTS], posed.vertices_m, person.faces)
        assert inside.mean() >= 0.9, (t, [COCO17_NAMES[i] for i, ok in zip(BODY_JOINTS, inside) if not ok])
    low = [person.pose(motion, float(t)).vertices_m[:, 2].min() for t in np.arange(0, motion.duration_s, 0.1)]
    assert min(low) > -0.04                       # no foot sinks into the ground
    assert np.percentile(low, 10) < 0.03          # and some touch it


def test_pose_is_deterministic(person: P.Person, motion: P.Motion) -> None:
    a, b = person.pose(motion, 0.737), person.pose(motion, 0.737)
    assert np.array_equal(a.vertices_m, b.vertices_m) and np.array_equal(a.joints_m, b.joints_m)
    assert a.vertices_m.dtype == np.float32 and a.vertices_m.shape == person.vertices_m.shape
    assert a.joints_m.shape == (17, 3) and np.isfinite(a.vertices_m).all()


def test_root_starts_over_the_origin_and_loops_continue(person: P.Person, motion: P.Motion) -> None:
    np.testing.assert_allclose(person.pose(motion, 0.0).root_m[:2], 0.0, atol=1e-5)
    d = motion.duration_s
    before, after = person.pose(motion, d - 1e-4), person.pose(motion, d + 1e-4)
    assert np.abs(before.vertices_m - after.vertices_m).max() < 0.01      # no jump at the loop point


def test_walk_and_run_advance_at_their_speed() -> None:
    person = P.load_person("walker")
    for name, lo, hi in (("walk", 0.8, 1.7), ("run", 2.0, 5.0)):
        m = P.load_motion(name)
        assert lo < m.speed_mps < hi, (name, m.speed_mps)
        r0, r3 = person.pose(m, 0.2).root_m, person.pose(m, 0.2 + 3 * m.duration_s).root_m
        assert abs((r3[0] - r0[0]) / (3 * m.duration_s) - m.speed_mps) < 1e-3
        assert abs(r3[1] - r0[1]) < 1e-3 and abs(r3[2] - r0[2]) < 1e-3
        xs = [person.pose(m, t).root_m[0] for t in np.arange(0, 3 * m.duration_s, 0.05)]
        assert np.all(np.diff(xs) > -0.02)      # forwards all the way (a stride may pause, never goes back)


def test_in_place_motions_stay_in_place(person: P.Person) -> None:
    for name in P.MOTIONS:
        m = P.load_motion(name)
        if m.speed_mps == 0:
            roots = np.array([person.pose(m, t).root_m for t in np.arange(0, 3 * m.duration_s, 0.1)])
            # the dance steps up to a metre to the side and back; the others stay within a stride
            assert np.abs(roots[:, :2]).max() < (1.2 if name == "dance" else 0.5), name
            np.testing.assert_allclose(roots[0], person.pose(m, m.duration_s).root_m, atol=1e-4)


def test_left_is_plus_y_in_every_frame(person: P.Person, motion: P.Motion) -> None:
    for t in np.arange(0, motion.duration_s, 0.2):
        posed = person.pose(motion, float(t))
        # in the pelvis's own frame: rotate the body so the hips' forward is +x
        j = posed.joints_m
        left = j[L["left_hip"]] - j[L["right_hip"]] + j[L["left_shoulder"]] - j[L["right_shoulder"]]
        yaw = math.atan2(-left[0], left[1])
        body = (j - j.mean(0)) @ _rz(-math.degrees(yaw)).T
        for lft, rgt in PAIRS_LR:
            assert body[lft, 1] > body[rgt, 1], (t, COCO17_NAMES[lft])
        assert abs(yaw) < math.radians(100)        # the body faces +x (give or take a dance move)


def test_people_are_distinct_and_of_their_height() -> None:
    heights = {"juggler": 1.78, "dancer": 1.65, "runner": 1.80, "walker": 1.75}
    seen = []
    for name in P.PEOPLE:
        p = P.load_person(name)
        assert abs(p.height_m - heights[name]) < 0.03, name
        idle = p.pose(P.load_motion("idle"), 1.0) if "idle" in P.MOTIONS else p.skin(*_identity())
        assert abs(idle.vertices_m[:, 2].max() - p.height_m) < 0.05, name
        assert p.colors.dtype == np.float32 and p.colors.min() >= 0 and p.colors.max() <= 1
        assert p.faces.dtype == np.int32 and p.faces.max() < len(p.vertices_m) and len(p.faces) <= 20000
        # per-vertex brightness noise: neighbours differ (flat colours read as soft to the focus map)
        edge = np.abs(p.colors[p.faces[:, 0]] - p.colors[p.faces[:, 1]]).sum(1)
        assert np.median(edge) > 0.03
        seen.append(np.concatenate([p.colors.mean(0), [p.height_m]]))
    for i in range(len(seen)):
        for k in range(i):
            assert np.abs(seen[i] - seen[k]).max() > 0.02


def test_baked_files_are_small() -> None:
    files = [*P.PEOPLE_DIR.glob("*.npz"), *P.MOTIONS_DIR.glob("*.npz")]
    assert {f.stem for f in files} >= set(P.PEOPLE) | set(P.MOTIONS)
    assert all(f.stat().st_size < 1_500_000 for f in files)
    assert sum(f.stat().st_size for f in files) < 5_000_000


def test_bad_names_and_times_get_one_line_errors() -> None:
    with pytest.raises(P.PeopleError, match="unknown person 'nobody'"):
        P.load_person("nobody")
    with pytest.raises(P.PeopleError, match="unknown motion"):
        P.load_motion("moonwalk")
    with pytest.raises(P.PeopleError, match="not finite"):
        P.load_person(P.PEOPLE[0]).pose(P.load_motion(P.MOTIONS[0]), float("nan"))
