"""Frame/state pairing of the renderer: sync (the state's own frame) and latest (the paper's)."""

from __future__ import annotations

import pytest

from facesculpt.nodes.renderer.pairing import FramePairer

MS = 1_000_000


def frames_and_states(n_frames: int, fit_every: int, latency_frames: int):
    """An interleaved stream like the graph's: a frame every 33 ms; the fitter takes every
    ``fit_every``-th frame and publishes its state ``latency_frames`` frames later."""
    events = []
    for i in range(n_frames):
        stamp = (i + 1) * 33 * MS
        events.append(("frame", stamp, f"frame{i}"))
        j = i - latency_frames
        if j >= 0 and j % fit_every == 0:
            events.append(("state", (j + 1) * 33 * MS, f"state{j}"))
    return events


def run(pairer: FramePairer, events):
    out = []
    for kind, stamp, payload in events:
        if kind == "frame":
            out += pairer.push_frame(stamp, payload)
        else:
            out += pairer.push_state(stamp, payload)
    return out


def test_sync_renders_each_state_on_its_own_frame():
    pairer = FramePairer("sync", capacity=10, timeout_ns=2000 * MS)
    pairs = run(pairer, frames_and_states(40, fit_every=2, latency_frames=3))
    drawn = [p for p in pairs if p.state is not None]
    assert len(drawn) == 19  # states for frames 0, 2, .., 36 (38 is still in flight)
    for p in drawn:
        assert p.frame == p.state.replace("state", "frame")
        assert p.lag_ns == 0
    stamps = [p.frame_stamp for p in pairs]
    assert stamps == sorted(stamps)
    assert pairer.counters["skipped_by_fitter"] == 18  # the odd frames the fitter never saw
    assert pairer.buffered <= 10


def test_latest_draws_newest_state_with_the_fitters_lag():
    pairer = FramePairer("latest", max_age_ns=1000 * MS)
    pairs = run(pairer, frames_and_states(40, fit_every=1, latency_frames=3))
    assert len(pairs) == 40  # every frame is rendered, none waits
    drawn = [p for p in pairs if p.state is not None]
    assert len(drawn) == 36
    # State j arrives just after frame j+3, so frame j+4 is the first drawn with it: the
    # mesh lags the face by the fitter's latency plus a frame (the paper's lag).
    assert {p.lag_ns for p in drawn} == {4 * 33 * MS}
    assert all(p.frame == f"frame{int(p.state[5:]) + 4}" for p in drawn)


def test_sync_buffer_is_bounded_and_lets_frames_through_when_the_fitter_stalls():
    pairer = FramePairer("sync", capacity=5, timeout_ns=10_000 * MS)
    out = []
    for i in range(20):
        out += pairer.push_frame((i + 1) * 33 * MS, i)
    assert pairer.buffered == 5
    assert [p.frame for p in out] == list(range(15))  # oldest first, without a face
    assert all(p.state is None for p in out)
    assert pairer.counters["buffer_overflow"] == 15
    # A state for a frame still buffered renders it and drops the older waiting frames.
    ready = pairer.push_state(18 * 33 * MS, "s17")
    assert [(p.frame, p.state) for p in ready] == [(17, "s17")]
    assert pairer.buffered == 2


def test_sync_timeout_passes_frames_of_a_faceless_stream():
    pairer = FramePairer("sync", capacity=100, timeout_ns=100 * MS)
    out = []
    for i in range(10):
        out += pairer.push_frame((i + 1) * 33 * MS, i)
    # Frames older than 100 ms (against the newest) come out, in order, without a face.
    assert [p.frame for p in out] == list(range(6))
    assert pairer.counters["timed_out"] == 6


def test_sync_state_without_face_passes_its_frame():
    pairer = FramePairer("sync")
    pairer.push_frame(1000, "f")
    ready = pairer.push_state(1000, None)
    assert len(ready) == 1 and ready[0].frame == "f" and ready[0].state is None


def test_latest_drops_a_stale_state():
    pairer = FramePairer("latest", max_age_ns=100 * MS)
    pairer.push_state(0, "s")
    assert pairer.push_frame(50 * MS, "a")[0].state == "s"
    assert pairer.push_frame(150 * MS, "b")[0].state is None
    assert pairer.counters["state_too_old"] == 1


def test_out_of_order_input_is_counted_not_used():
    pairer = FramePairer("sync")
    pairer.push_frame(2000, "b")
    assert pairer.push_frame(1000, "a") == []
    pairer.push_state(2000, "s")
    assert pairer.push_state(1000, "old") == []
    assert pairer.counters["frame_out_of_order"] == 1
    assert pairer.counters["state_out_of_order"] == 1


def test_bad_configuration_is_refused():
    with pytest.raises(ValueError, match="pairing mode"):
        FramePairer("newest")
    with pytest.raises(ValueError, match="capacity"):
        FramePairer("sync", capacity=0)


def test_sync_pairs_a_state_that_arrives_before_its_frame():
    # Frames (1.2 MB) and states (small) travel on different sockets: a state may come first.
    pairer = FramePairer("sync", capacity=4)
    assert pairer.push_state(1000, "s1") == []
    ready = pairer.push_frame(1000, "f1")
    assert [(p.frame, p.state) for p in ready] == [("f1", "s1")]
    pairer.push_state(3000, "s3")           # frame 2000 never gets a state, frame 3000 is late
    assert pairer.push_frame(2000, "f2") == []
    ready = pairer.push_frame(3000, "f3")
    assert [(p.frame, p.state) for p in ready] == [("f3", "s3")]
    assert pairer.counters["skipped_by_fitter"] == 1 and pairer.buffered == 0
    # An early state whose frame never comes is dropped once a newer frame arrives.
    pairer.push_state(4000, "s4")
    pairer.push_frame(5000, "f5")
    assert pairer.counters["state_without_frame"] == 1


def test_sync_keeps_the_mesh_on_the_face_while_latest_lags_a_slow_fitter(data_dir, models_dir):
    """Real frames (d3, a talking head), the real detector and fitter (face mesh, dense), a slow
    fitter (takes every 3rd frame, its state comes 3 frames later), the compositor drawing each
    pair. The mesh drawn lies where the state puts it (state.projected); the face in the
    rendered frame is where a fresh detection finds it. sync: they agree; latest: the lag."""
    import numpy as np

    from benchmarks.renderer_scene import read_frames
    from facesculpt.nodes.fitter import FitterConfig, facemesh_model, make_fitter
    from facesculpt.nodes.landmarks import LandmarkDetector
    from facesculpt.nodes.renderer import Compositor

    frames = read_frames(data_dir, "d3", count=30)
    H, W = frames[0].shape[:2]
    model = facemesh_model()
    detector = LandmarkDetector(models_dir)
    fitter = make_fitter(model, FitterConfig(smoothing=False), (W, H))
    states = [fitter.fit(detector.detect(f)[0].points, stamp=i / 30) for i, f in enumerate(frames)]
    comp = Compositor(W, H)
    latency = 3
    errors = {}
    for mode in ("sync", "latest"):
        pairer = FramePairer(mode, capacity=10, timeout_ns=10**12, max_age_ns=10**12)
        errors[mode] = []
        for i, frame in enumerate(frames):
            pairs = pairer.push_frame(i, frame)
            if i >= latency and (i - latency) % latency == 0:
                pairs += pairer.push_state(i - latency, states[i - latency])
            for p in pairs:
                st = p.state
                if st is None:  # latest: before the first state the frame passes through
                    continue
                out = comp.render(p.frame, st.vertices, st.projected, model.triangles, st.vertices)
                seen = detector.detect(out)[0].points[:, :2]
                errors[mode].append(float(np.median(np.linalg.norm(seen - st.projected, axis=1))))
    comp.release()
    assert len(errors["sync"]) == 9 and len(errors["latest"]) == 26
    assert max(errors["sync"]) <= 2.0
    assert np.median(errors["latest"]) >= 5.0
