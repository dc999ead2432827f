"""The camera node: frames from a webcam, a video file, a still image or a bag
on `camera/image`, stamped with their capture time, with intrinsics K. An RGB-D source
(:mod:`.rgbd_sources`: a RealSense, a folder of colour + depth PNGs, an RGB-D bag) adds each
frame's depth image with its own K (docs/guide/depth-cameras.md).

Live (``wait_for`` empty, the default) the camera reads at its pace and the graph keeps up as it
can. It is paced by the renderer (``pace_by: render/done``, the default): a frame goes out only
while fewer than ``pace_in_flight`` sent frames wait for their acknowledgement. A file, bag or
image (``pace_reads: auto``) is then not read meanwhile: the frame a tick could not send is read
and sent with the next acknowledgement (counter ``held``), so no frame is decoded only to be
dropped and the source plays at the pace the graph draws. A webcam delivers frames whether read
or not: the newest one read meanwhile goes out with the next acknowledgement (older ones are
skipped, counter ``skipped_busy``). A graph that cannot keep the camera's rate then spends no
work on frames it would never render, and no stage queues frames behind a slower one. Without a publisher of
``pace_by`` (no renderer), or with ``pace_by`` empty, every frame goes out and latest-only
subscribers skip the frames they had no time for.

Offline (``wait_for: render/done``, for a replay or demo that writes a file) it runs in lockstep
with the renderer: a frame goes out only while fewer than ``max_in_flight`` sent frames wait for
their :class:`~facesculpt.msgs.FrameDone`, no frame is skipped, and at the end of the source the
camera waits for the last ones before it ends, so every frame reaches the file. A frame still
unacknowledged after ``resend_s`` is published again (a node that connected after it went out
missed it; the renderer ignores a copy of a frame it already has), and so is every frame in flight
``LOCKSTEP_SETTLE_S`` after the graph changed (a node joined: a respawned fitter lost the frame it
was fitting when it was killed; counter ``resent_on_join``); one unacknowledged after
``ack_timeout_s`` is given up (counter ``ack_timeout``) and the camera sends on.

With ``analysis_pixels`` set, each frame also goes out on ``camera/analysis`` halved until it
holds at most that many pixels (``facesculpt.geometry.halving``), for the landmarks
(``image_topic: camera/analysis``): the analysis path then never receives the full frame.
"""

from __future__ import annotations

import time
from collections import OrderedDict, deque

import numpy as np

from facesculpt.geometry.halving import halve, halved_intrinsics, halvings
from facesculpt.msgs import FrameDone, Image
from facesculpt.runtime.node import Node
from facesculpt.runtime.parameters import ConfigurationError, Param, option_params
from facesculpt.runtime.qos import EVERY_MESSAGE

from .intrinsics import IntrinsicsOptions, intrinsics_from_fov
from .rgbd_sources import RGBDFrame, depth_fields, resized_intrinsics
from .source_opening import open_source
from .sources import RESIZE_MODES, SourceError, resize_frame

# Lockstep: how often the camera looks at its pacing and its acknowledgement deadlines, s (the
# acknowledgements themselves send the next frame at once).
LOCKSTEP_TICK_S = 0.01
# Lockstep: the first frame waits this long after its subscribers are there, so that the nodes
# further down (the fitter on landmarks, ...) have connected too (their master links look for
# new publishers every 0.1 s); one that still missed it gets it again after resend_s, s.
LOCKSTEP_SETTLE_S = 0.3
# Paced: a renderer slower than pace_timeout_s (a loaded machine) would see frames given up while
# it still works on them, and each give-up lets one more frame in to be dropped downstream. The
# timeout follows the acknowledgements' recent round trips: PACE_TIMEOUT_GAIN times their 90th
# percentile over the last PACE_RECENT_ACKS, never below pace_timeout_s nor above
# PACE_TIMEOUT_CAP times it (a renderer that died must not hold the camera for long).
PACE_TIMEOUT_GAIN = 2.0
PACE_RECENT_ACKS = 32
PACE_TIMEOUT_CAP = 4.0


class CameraNode(Node):
    """Publishes camera/image from a webcam, video, image or bag."""

    NAME = "camera"
    TOPICS = ("camera/image", "camera/analysis")
    PARAMS = {
        "source": Param("0", "webcam index, video file, image file, bag:FILE, embedded, or an RGB-D camera: "
                             "realsense[:SERIAL] or a folder of colour + 16-bit depth PNGs"),
        "width": Param(0, "resize to this width, px (0: keep; aspect kept if height is 0)", range=(0, 16384)),
        "height": Param(0, "resize to this height, px (0: keep; aspect kept if width is 0)", range=(0, 16384)),
        "resize": Param("fit", "with width and height both set: fit (largest size inside, aspect kept), "
                               "fill (cover and crop the centre, aspect kept) or stretch", choices=RESIZE_MODES),
        "fps": Param(0.0, "pacing, frames/s; 0: the source's own rate; -1: as fast as possible", range=(-1.0, 1000.0)),
        "loop": Param(False, "restart a video or bag at its end"),
        "motion": Param(False, "still image: move a virtual camera over it"),
        **option_params(IntrinsicsOptions(), ("fov_deg",)),
        "K": Param([], "9 numbers, row-major, for the output size (empty: from fov_deg)"),
        "max_frames": Param(0, "stop after this many frames (0: no limit)", range=(0, None)),
        "wait_subscribers": Param(0, "hold the first frame until this many subscribers listen (recording)",
                                  range=(0, 1000)),
        "wait_timeout_s": Param(10.0, "longest hold for wait_subscribers (and, with wait_for, for the "
                                      "acknowledging publisher), s", range=(0.0, 3600.0)),
        "wait_for": Param("", "offline lockstep: the topic of FrameDone acknowledgements (render/done) to wait "
                              "for before sending more frames, so every frame is processed and written; "
                              "\"\": live, at the source's pace (see pace_by)", topic=True),
        "max_in_flight": Param(1, "with wait_for: frames sent but not yet acknowledged (1: no latest-only "
                                  "node can skip a frame; more overlaps the stages, but a node that keeps "
                                  "only the newest frame may then skip one)", range=(1, 4)),
        "ack_timeout_s": Param(10.0, "with wait_for: longest wait for a frame's acknowledgement before "
                                     "sending on (counted as ack_timeout), also at the end of the source, s",
                               range=(0.1, 3600.0)),
        "analysis_pixels": Param(0, "also publish camera/analysis: the frame halved until it holds at most this "
                                    "many pixels, for the landmarks to track on (landmarks.image_topic); "
                                    "0: no such topic", range=(0, None)),
        "pace_by": Param("render/done", "live: the topic of FrameDone acknowledgements; a frame goes out only "
                                        "while fewer than pace_in_flight sent frames wait for theirs, and the "
                                        "newest frame read meanwhile goes out with the next one (older ones are "
                                        "skipped); every frame goes out while nothing publishes the topic, or "
                                        "with \"\"", topic=True),
        "pace_in_flight": Param(2, "with pace_by: frames sent but not yet acknowledged (2: the analysis of one "
                                   "overlaps the rendering of the one before)", range=(1, 8)),
        "pace_reads": Param("auto", "with pace_by: on: the next frame is read only when it may go out (none "
                                    "read to be dropped; a file plays at the graph's pace); off: read at the "
                                    "source's pace, the newest read goes out; auto: off for a webcam, on otherwise",
                            choices=("auto", "on", "off")),
        "pace_timeout_s": Param(0.5, "with pace_by: a sent frame unacknowledged after this long no longer "
                                     "holds the next one back (longer while the acknowledgements come later: "
                                     "twice their recent round trip, up to 4 times this), s",
                                range=(0.01, 60.0)),
        "resend_s": Param(2.0, "with wait_for: publish a frame again when its acknowledgement has not come "
                               "after this long (a node that connected late missed it; the renderer ignores "
                               "a copy of a frame it has), s; 0: never", range=(0.0, 3600.0)),
    }

    def setup(self):
        p = self.params
        self.pub = self.advertise("camera/image", Image)
        self.analysis_pub = self.advertise("camera/analysis", Image) if p.analysis_pixels else None
        try:
            self.source = open_source(p.source, loop=p.loop, motion=p.motion, fps=p.fps if p.fps > 0 else 30.0)
        except (SourceError, FileNotFoundError) as exc:  # no such camera or file: a respawn cannot help
            raise ConfigurationError(f"camera: {exc}") from None
        self.frames = self.source.frames()
        rate = p.fps if p.fps > 0 else (self.source.native_fps if p.fps == 0 else 0.0)
        self.period = 1.0 / rate if rate > 0 else 0.0
        self.sent = 0
        self.K_fixed = None
        if p.K:
            if len(p.K) != 9:
                raise ValueError(f"camera.K needs 9 numbers, got {len(p.K)}")
            self.K_fixed = np.asarray(p.K, dtype=np.float64).reshape(3, 3)
        self._K_cache: dict[tuple, np.ndarray] = {}
        self.lockstep = bool(p.wait_for)
        # Lockstep and paced: seq -> [the Image (paced: None), monotonic time first sent, monotonic
        # time last sent, its stamp].
        self.in_flight: OrderedDict[int, list] = OrderedDict()
        self.ack_round_trips: deque[float] = deque(maxlen=PACE_RECENT_ACKS)  # paced: s, send to acknowledgement
        self.given_up: OrderedDict[int, tuple[float, int]] = OrderedDict()  # paced: seq -> (sent, stamp) timed out
        self.next_send_at = 0.0   # lockstep pacing: monotonic time the next frame may go out
        self.ended = False        # lockstep: the source is done; waiting for the last acknowledgements
        self.done_sub = None
        self.settle_until = 0.0   # lockstep: monotonic time the first frame may go out
        self.seen_registrations = 0  # lockstep: the master's node registrations when last looked at
        self.joined_at = 0.0      # lockstep: monotonic time the graph last changed (0: no resend due)
        self.paced = bool(p.pace_by) and not self.lockstep
        self.pending = None       # paced: the newest frame read while the in-flight frames were full
        # paced: read only when a frame may go out (not for a webcam, whose frames come anyway)
        self.reads_paced = self.paced and (p.pace_reads == "on" or (p.pace_reads == "auto" and not self.source.live))
        self.held = False         # reads paced: a tick left its frame unread; the next acknowledgement reads it
        if self.lockstep or self.paced:
            self.done_sub = self.subscribe(p.wait_for or p.pace_by, FrameDone, self.on_done, qos=EVERY_MESSAGE)
        waits = p.wait_subscribers or self.lockstep
        self.wait_until = time.monotonic() + p.wait_timeout_s if waits else 0.0
        self.log.info("%s at %s%s", self.source.description, f"{rate:.1f} fps" if rate else "full speed",
                      f", in lockstep with {p.wait_for} ({p.max_in_flight} in flight)" if self.lockstep else
                      f", paced by {p.pace_by} ({p.pace_in_flight} in flight)" if self.paced else "")
        self.tick = self.timer(LOCKSTEP_TICK_S if self.lockstep else self.period, self.on_tick)

    def intrinsics(self, width: int, height: int) -> np.ndarray:
        if self.K_fixed is not None:
            return self.K_fixed
        key = (width, height)
        if key not in self._K_cache:
            self._K_cache[key] = intrinsics_from_fov(width, height, self.params.fov_deg)
        return self._K_cache[key]

    def on_tick(self):
        if self.wait_until and not self._ready_to_start():
            return
        if self.lockstep:
            self._advance()
        elif self.reads_paced and not self._pace_allows():
            if not self.held:
                self.count("held")
            self.held = True
        else:
            self._publish_live()

    def _publish_live(self) -> None:
        """Live: read and publish the next frame; stop after ``max_frames``."""
        self.held = False
        if self._publish_next() and self.params.max_frames and self.sent >= self.params.max_frames:
            self.shutdown()

    def _ready_to_start(self) -> bool:
        """Whether the first frame may go out: ``wait_subscribers`` listen and, in lockstep, the
        acknowledging publisher is known (or ``wait_timeout_s`` passed)."""
        p = self.params
        missing = []
        if self.pub.subscriber_count() < p.wait_subscribers:
            missing.append(f"{p.wait_subscribers} subscribers of {self.pub.topic}")
        if self.done_sub is not None and not self.done_sub.endpoints:
            missing.append(f"a publisher of {self.done_sub.topic}")
        now = time.monotonic()
        if missing and now < self.wait_until:
            return False
        if missing:
            self.log.warning("starting without %s after %.1f s", " and ".join(missing), p.wait_timeout_s)
        elif self.lockstep:
            self.settle_until = self.settle_until or now + LOCKSTEP_SETTLE_S
            if now < self.settle_until:
                return False
        self.wait_until = 0.0
        return True

    def _publish_next(self) -> bool:
        """Read, resize and publish the next frame (paced and held back: keep it as the pending
        frame); False at the end of the source (or on its error)."""
        try:
            frame, stamp = next(self.frames)
            self._report_problems()
        except StopIteration:
            self._report_problems()
            self.log.info("end of %s after %d frames", self.source.description, self.sent)
            self._end()
            return False
        except SourceError as exc:
            self.count("source_errors")
            self.log.error("%s", exc)
            self._end()
            return False
        self.count("frames_read")
        if self.paced and not self._pace_allows():
            if self.pending is not None:
                self.count("skipped_busy")
            self.pending = (frame, stamp)
            return True
        self.pending = None
        self._send(frame, stamp)
        return True

    def _send(self, frame: np.ndarray | RGBDFrame, stamp: int) -> None:
        p = self.params
        rgbd, extra = (frame, {}) if isinstance(frame, RGBDFrame) else (None, {})
        if rgbd is not None:   # an RGB-D source: its depth goes along with its own K (docs/guide/depth-cameras.md)
            frame = rgbd.color
            h0, w0 = frame.shape[:2]
            K0 = rgbd.K if rgbd.K is not None and self.K_fixed is None else self.intrinsics(w0, h0)
            extra = depth_fields(rgbd, K0)
        frame = resize_frame(frame, p.width, p.height, p.resize)
        h, w = frame.shape[:2]
        K = self.intrinsics(w, h) if rgbd is None or self.K_fixed is not None else \
            resized_intrinsics(K0, (w0, h0), p.width, p.height, p.resize)
        self.sent += 1
        msg = Image(stamp=stamp, seq=self.sent, frame_id="camera", image=np.ascontiguousarray(frame), K=K, **extra)
        self.pub.publish(msg)
        if self.analysis_pub is not None:
            self._publish_analysis(msg)
        if self.lockstep or self.paced:
            now = time.monotonic()
            self.in_flight[self.sent] = [msg if self.lockstep else None, now, now, stamp]

    def _publish_analysis(self, msg: Image) -> None:
        """camera/analysis: ``msg``'s frame halved to at most ``analysis_pixels`` (the frame itself
        when it holds no more), same stamp and seq, its K for the copy."""
        h, w = msg.image.shape[:2]
        times = halvings(w, h, self.params.analysis_pixels)
        self.analysis_pub.publish(Image(stamp=msg.stamp, seq=msg.seq, frame_id=msg.frame_id,
                                        image=halve(msg.image, times), K=halved_intrinsics(msg.K, times),
                                        halvings=times, frame_size=[w, h]))

    def _pace_allows(self) -> bool:
        """Paced: whether a frame may go out now (fewer than ``pace_in_flight`` sent frames younger
        than ``pace_timeout_s`` wait for their acknowledgement, or nothing acknowledges at all)."""
        if not self.done_sub.endpoints:
            self.in_flight.clear()
            return True
        limit = time.monotonic() - self.pace_timeout_s()
        while self.in_flight and next(iter(self.in_flight.values()))[1] < limit:
            seq, (_, first_sent, _, stamp) = self.in_flight.popitem(last=False)
            self.count("pace_timeout")
            self.given_up[seq] = (first_sent, stamp)  # its late acknowledgement still says how slow
            while len(self.given_up) > PACE_RECENT_ACKS:
                self.given_up.popitem(last=False)
        return len(self.in_flight) < self.params.pace_in_flight

    def pace_timeout_s(self) -> float:
        """Paced: how long a sent frame may hold the next ones back, s (see PACE_TIMEOUT_GAIN)."""
        least = self.params.pace_timeout_s
        if not self.ack_round_trips:
            return least
        recent = float(np.percentile(np.fromiter(self.ack_round_trips, float), 90))
        return min(PACE_TIMEOUT_CAP * least, max(least, PACE_TIMEOUT_GAIN * recent))

    def _end(self) -> None:
        """No more frames: live, stop now; in lockstep, once the frames in flight are acknowledged."""
        if self.lockstep:
            self.ended = True
        else:
            self.shutdown()

    # -- lockstep ------------------------------------------------------------------------------
    def _advance(self) -> None:
        """Give up acknowledgements past ``ack_timeout_s``, send what the window and the pacing
        allow, and stop once the source ended and nothing is in flight."""
        p = self.params
        now = time.monotonic()
        if self.link.registrations != self.seen_registrations:
            self.seen_registrations, self.joined_at = self.link.registrations, now
        # A node joined the graph: once its links are connected, what is in flight goes out again.
        rejoin = bool(p.resend_s and self.joined_at) and now - self.joined_at >= LOCKSTEP_SETTLE_S
        for seq, entry in list(self.in_flight.items()):
            msg, first_sent, last_sent, _ = entry
            if now - first_sent >= p.ack_timeout_s:
                del self.in_flight[seq]
                self.count("ack_timeout")
                self.log.warning("frame %d: no acknowledgement on %s within %.1f s; sending on",
                                 seq, self.done_sub.topic, p.ack_timeout_s)
            elif (p.resend_s and now - last_sent >= p.resend_s) or (rejoin and last_sent < self.joined_at):
                self.pub.publish(msg)
                if self.analysis_pub is not None:
                    self._publish_analysis(msg)
                entry[2] = now
                joined = rejoin and now - last_sent < p.resend_s
                self.count("resent_on_join" if joined else "resent")
                self.log.info("frame %d: no acknowledgement after %.1f s; sent again%s", seq, now - first_sent,
                              " (a node joined the graph)" if joined else "")
        if rejoin:
            self.joined_at = 0.0
        while not self.ended and len(self.in_flight) < p.max_in_flight and now >= self.next_send_at:
            if p.max_frames and self.sent >= p.max_frames:
                self._end()
            elif self._publish_next():
                self.next_send_at = now + self.period
        if self.next_send_at > now:  # wake up when the pacing allows the next frame, not a tick later
            self.tick.next_at = min(self.tick.next_at, self.next_send_at)
        if self.ended and not self.in_flight and self.running:
            c = self.counters
            self.log.info("all %d frames handled downstream (%d acknowledged, %d skipped, %d timed out)",
                          self.sent, c.get("acknowledged", 0), c.get("ack_skipped", 0), c.get("ack_timeout", 0))
            self.shutdown()

    def on_done(self, msg: FrameDone) -> None:
        """The renderer handled frame ``msg.seq``: it leaves the window, and so do older frames
        still in it (a node downstream skipped them: they will never be acknowledged)."""
        sent = self.in_flight.get(msg.seq)
        if sent is None or sent[3] != msg.stamp:
            late = self.given_up.pop(msg.seq, None)
            if late is not None and late[1] == msg.stamp:
                self.ack_round_trips.append(time.monotonic() - late[0])
                self.count("ack_late")  # after its timeout: the next timeouts wait longer
            else:
                self.count("ack_unknown")  # another camera's frame
            return
        for seq in list(self.in_flight):
            if seq >= msg.seq:
                break
            del self.in_flight[seq]
            self.count("ack_skipped")
        del self.in_flight[msg.seq]
        self.count("acknowledged")
        if self.paced:
            self.ack_round_trips.append(time.monotonic() - sent[1])
            if self.pending is not None and self._pace_allows():
                frame, stamp = self.pending
                self.pending = None
                self._send(frame, stamp)
            elif self.held and self._pace_allows():   # the frame a tick held back: read now, sent now
                self._publish_live()
        elif self.wait_until == 0.0:
            self._advance()

    def _report_problems(self) -> None:
        problems = getattr(self.source, "problems", None)
        while problems:
            self.count("source_errors")
            self.log.warning("%s", problems.pop(0))

    def teardown(self):
        if hasattr(self, "source"):
            self.source.close()
