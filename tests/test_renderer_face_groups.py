"""The renderer gathers the face states of one frame before pairing it (several faces)."""

from facesculpt.nodes.renderer.face_groups import FaceGroups


def test_a_group_is_ready_when_all_its_faces_came_in_face_order():
    g = FaceGroups()
    assert g.push(10, "b", faces=2, face_id=5) == []
    assert g.push(10, "a", faces=2, face_id=3) == [(10, ["a", "b"])]
    assert g.push(20, "c", faces=1, face_id=0) == [(20, ["c"])]


def test_an_empty_state_is_a_frame_without_a_face():
    g = FaceGroups()
    assert g.push(10, None, faces=0) == [(10, [])]


def test_a_group_missing_a_state_is_handed_on_when_a_newer_frame_arrives():
    g = FaceGroups()
    assert g.push(10, "a", faces=2, face_id=0) == []
    assert g.push(20, None, faces=0) == [(10, ["a"]), (20, [])]
    assert g.counters == {"incomplete_group": 1}


def test_capacity_bounds_the_open_groups():
    g = FaceGroups(capacity=2)
    out = []
    for stamp in (30, 20, 10):  # out of order: each older one stays open
        out += g.push(stamp, stamp, faces=2, face_id=0)
    assert out == [(30, [30])] and g.counters["incomplete_group"] == 1
