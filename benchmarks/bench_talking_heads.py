"""Talking heads at a few kbit/s (issue 19): reenactment and model-based coding on the shared videos.

    python -m benchmarks.bench_talking_heads reenact [--drivers d0,d3,d12] [--sources astronaut,d12]
    python -m benchmarks.bench_talking_heads coding [--videos d0,d3,d12] [--components 12] [--frames N]
        [--body both|on|off] [--stills DIR] [--no-h264] [--time-reps N]
    python -m benchmarks.bench_talking_heads graph [--videos d3,s18] [--fps 30]

reenact: each source (``astronaut``: the embedded photo, mouth open showing teeth; a video name:
its first frame) is driven by each video; the output is fitted again (its own neutral learned
from its first 30 frames, as the driver's) and each expression component of the output is
correlated with the driver's over the frames, for the components the driver moves (standard
deviation over 1 %IOD, or 0.05 for eye closure). A frame strip (source | driver at its widest
mouth | result) is written per pair with ``--strips DIR``.

coding: each video encoded (``.fsc``) and decoded; the per-frame stream's bitrate and the whole
file's; face-region PSNR/SSIM (the convex hull of the original frame's fit) of the decode against
the input, and the PSNR of the band below the jaw (neck, collar and the background beside them:
``facesculpt.app.coding.neck_band``), each with the decoder's body motion off (the decoder before
issue 51: only the head moves) and on (the chin's motion carried over the body below the jaw),
on the same stream; then, for the body motion's decode, H.264 (libx264 through PyAV, medium preset, one pass at a target bitrate; the
bitrate it really spent is reported) on the same frames at a ladder of bitrates, and the bitrate
H.264 needs for the model stream's PSNR (interpolated on the ladder, log bitrate).

graph: facesculpt/launch/coding.yaml on a video at ``--fps``, scaled to the paper's pixel count (856x480)
at its own aspect as `facesculpt bench` does (camera, landmarks, fitter and encoder; the
coded topics on tcp loopback to the decoder node): decoded frames out per second over the coded
part, latency from capture to the decoded frame (p50/p99), coding/frame's bytes on the wire (the
record and the graph's framing) per second, the key's size, the bases sent (the first and the ones
learnt again) and all coded payload (records, key, bases) per second over the coded part.
"""

from __future__ import annotations

import argparse
import io
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

from facesculpt.nodes.fitter.config import FitterConfig

REPO = Path(__file__).resolve().parent.parent


def _video(name: str) -> Path:
    from facesculpt.paths import shared_data_dir

    data = shared_data_dir()
    if data is None:
        raise SystemExit("shared data not found: set FACESCULPT_DATA")
    return data / "video" / f"{name}.mp4"


def _frames(path, limit: int = 10**6):
    cap, out = cv2.VideoCapture(str(path)), []
    while len(out) < limit:
        ok, frame = cap.read()
        if not ok:
            break
        out.append(frame)
    fps = cap.get(cv2.CAP_PROP_FPS)
    cap.release()
    return out, fps


def _expressions(frames, fps, neutral_frames=30):
    from facesculpt.app.pipeline import Pipeline
    from facesculpt.nodes.fitter.expression import NAMES

    pipe = Pipeline("facemesh", fit=FitterConfig(neutral_frames=neutral_frames))
    pipe.calibrate(frames[:neutral_frames], fps)
    fits, E = [], []
    for i, frame in enumerate(frames):
        fit = pipe.fit_frame(frame, i / fps)
        fits.append(fit)
        E.append(fit.expression if fit is not None else np.full(len(NAMES), np.nan))
    return pipe, np.array(E), fits


def bench_reenact(args) -> None:
    from facesculpt.app.reenactment import Reenactor, fit_source, inner_lip_ids
    from facesculpt.nodes.fitter.expression import NAMES
    from facesculpt.nodes.renderer.mouth_interior import opening_px
    from facesculpt.paths import embedded_face_image

    for name in args.sources.split(","):
        image = cv2.imread(str(embedded_face_image())) if name == "astronaut" else _frames(_video(name), 1)[0][0]
        source = fit_source(image)
        for drv in args.drivers.split(","):
            frames, fps = _frames(_video(drv))
            pipe, driver, fits = _expressions(frames, fps)
            opening = opening_px(source.fit.projected[inner_lip_ids(pipe.model)])
            re = Reenactor(source, pipe.model, pipe.neutral)
            outs = [re.render(f) for f in fits]
            re.close()
            output = _expressions(outs, fps)[1]
            ok = np.isfinite(driver).all(1) & np.isfinite(output).all(1)
            rows = []
            for k, comp in enumerate(NAMES):
                if np.std(driver[ok, k]) > (0.05 if comp.startswith("eye_close") else 1.0):
                    rows.append((comp, np.corrcoef(driver[ok, k], output[ok, k])[0, 1]))
            r = np.array([c for _, c in rows])
            print(f"{name} (mouth {opening:.1f} px) <- {drv} ({ok.sum()}/{len(frames)} frames): jaw_open r = "
                  f"{np.corrcoef(driver[ok, 0], output[ok, 0])[0, 1]:.3f}; {len(rows)} moving components: "
                  f"mean r {r.mean():.3f}, median {np.median(r):.3f}, {int((r >= 0.8).sum())} >= 0.8")
            print("    " + " ".join(f"{c}:{v:.2f}" for c, v in rows))
            if args.strips:
                i = int(np.nanargmax(driver[:, 0]))
                h = image.shape[0]
                d = cv2.resize(frames[i], (round(frames[i].shape[1] * h / frames[i].shape[0]), h))
                Path(args.strips).mkdir(parents=True, exist_ok=True)
                cv2.imwrite(str(Path(args.strips) / f"reenact_{name}_{drv}.png"), np.hstack([image, d, outs[i]]))


def h264(frames, fps, kbps):
    """The frames through libx264 at ``kbps`` (one pass): (decoded frames, kbit/s really spent)."""
    import av

    buf = io.BytesIO()
    with av.open(buf, "w", format="mp4") as container:
        stream = container.add_stream("libx264", rate=int(round(fps)))
        stream.width, stream.height, stream.pix_fmt = frames[0].shape[1], frames[0].shape[0], "yuv420p"
        stream.bit_rate = int(kbps * 1000)
        stream.options = {"preset": "medium"}
        for f in frames:
            for packet in stream.encode(av.VideoFrame.from_ndarray(f, format="bgr24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    size = buf.getbuffer().nbytes
    buf.seek(0)
    with av.open(buf) as container:
        out = [fr.to_ndarray(format="bgr24") for fr in container.decode(video=0)]
    return out, size * 8 / (len(frames) / fps) / 1000


def _quality(decoded, frames, analysis):
    from facesculpt.app.coding import face_region_quality

    q = [face_region_quality(o, f, p) for o, f, p, ok in zip(decoded, frames, analysis.projected, analysis.present)
         if ok]
    return float(np.mean([x[0] for x in q])), float(np.mean([x[1] for x in q]))


def _neck_psnr(decoded, frames, analysis):
    """Mean PSNR (dB) over the frames with a face of the band below the jaw (:func:`neck_band`)."""
    from facesculpt.app.coding import neck_band, region_psnr

    q = [region_psnr(o, f, neck_band(f.shape, p)) for o, f, p, ok in
         zip(decoded, frames, analysis.projected, analysis.present) if ok]
    return float(np.nanmean(q))


def _decode(path, n, body_motion):
    """(the n frames decoded, ms a frame)."""
    import time

    from facesculpt.app.coding import decode_file

    stream, decoder = decode_file(path, body_motion=body_motion)
    try:
        t0 = time.perf_counter()
        frames = [decoder.frame(i) for i in range(n)]
        return frames, (time.perf_counter() - t0) * 1e3 / max(n, 1)
    finally:
        decoder.close()


def _time_body(frames, analysis, args):
    """Decode time with the body motion on over off: ``--time-reps`` passes each, alternated, medians."""
    from facesculpt.app.coding import encode

    with tempfile.TemporaryDirectory() as tmp:
        encode(analysis, Path(tmp) / "v.fsc", components=args.components)
        ms = {False: [], True: []}
        for _ in range(args.time_reps):
            for body in (False, True):
                ms[body].append(_decode(Path(tmp) / "v.fsc", len(frames), body)[1])
    off, on = np.median(ms[False]), np.median(ms[True])
    print(f"    decode time: body off {off:.1f} ms/frame, on {on:.1f} ms/frame: on / off {on / off:.2f}x "
          f"(medians of {args.time_reps} alternated passes)")


def _stills(out_dir, name, frames, by_body, fps):
    """Writes ``coding_NAME.png``: rows at 1, 2 and 3 s (as far as the video goes): input | decoded
    with the body's motion off (the decoder before issue 51) | on."""
    rows = sorted({min(int(round(s * fps)), len(frames) - 1) for s in (1.0, 2.0, 3.0)})
    strip = np.vstack([np.hstack([frames[i], by_body[False][i], by_body[True][i]]) for i in rows])
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(Path(out_dir) / f"coding_{name}.png"), strip)


def bench_coding(args) -> None:
    from facesculpt.app.coding import analyse, encode

    bodies = {"on": (True,), "off": (False,), "both": (False, True)}[args.body]
    for name in args.videos.split(","):
        frames, fps = _frames(_video(name), args.frames)
        analysis = analyse(frames, fps)
        by_body, ms = {}, {}
        with tempfile.TemporaryDirectory() as tmp:
            sizes = encode(analysis, Path(tmp) / "v.fsc", components=args.components)
            for body in bodies:
                by_body[body], ms[body] = _decode(Path(tmp) / "v.fsc", len(frames), body)
        seconds = len(frames) / fps
        stream_kbps = sizes["stream"] * 8 / seconds / 1000
        print(f"{name} ({len(frames)} frames, {fps:g} fps): .fsc per-frame stream {stream_kbps:.2f} kbit/s, "
              f"whole file {sizes['total'] * 8 / seconds / 1000:.1f} kbit/s (header {sizes['total'] - sizes['records']} "
              f"bytes: keyframe {sizes['keyframe']}, arrays {sizes['arrays']}; records {sizes['records']} bytes)")
        for body, decoded in by_body.items():
            psnr, ssim = _quality(decoded, frames, analysis)
            print(f"    body motion {'on ' if body else 'off'}: face region PSNR {psnr:.2f} dB, SSIM {ssim:.3f}; "
                  f"neck band PSNR {_neck_psnr(decoded, frames, analysis):.2f} dB; decode {ms[body]:.1f} ms/frame")
        if len(ms) == 2 and args.time_reps:
            _time_body(frames, analysis, args)
        if args.stills and len(by_body) == 2:
            _stills(args.stills, name, frames, by_body, fps)
        if args.no_h264:
            continue
        ladder = []
        for target in (stream_kbps, sizes["total"] * 8 / seconds / 1000, 16, 32, 64, 128, 256):
            out, real = h264(frames, fps, target)
            hp, hs = _quality(out, frames, analysis)
            ladder.append((real, hp))
            print(f"    H.264 target {target:6.1f} -> {real:6.1f} kbit/s: PSNR {hp:.2f} dB, SSIM {hs:.3f}")
        ladder.sort()
        rates, psnrs = np.log([r for r, _ in ladder]), np.array([p for _, p in ladder])
        if psnrs.min() <= psnr <= psnrs.max():
            need = float(np.exp(np.interp(psnr, np.maximum.accumulate(psnrs), rates)))
            print(f"    H.264 needs about {need:.0f} kbit/s for the model stream's {psnr:.2f} dB")
        else:
            print(f"    the model stream's {psnr:.2f} dB lies outside H.264's ladder ({psnrs.min():.2f}..{psnrs.max():.2f})")


def bench_graph(args) -> None:
    import os
    import subprocess
    import time

    from facesculpt.app.bench import bench_size
    from facesculpt.app.bench_graph import free_port
    from facesculpt.msgs import CodedBasis, CodedFrame, CodedKey, Image, encode
    from facesculpt.runtime.node import Node
    from facesculpt.runtime.qos import EVERY_MESSAGE, LATCHED

    print(f"decoder head_motion={args.head_motion}")
    print("| video | camera fps | decoded frames/s | latency p50 / p99 ms | coding/frame on the wire | record | key bytes "
          "| bases sent: bytes | all coding/ payload |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for name in args.videos.split(","):
        with tempfile.TemporaryDirectory() as tmp, open(Path(tmp) / "launch.log", "w+") as log:
            address = f"tcp://127.0.0.1:{free_port()}"
            env = dict(os.environ, FACESCULPT_MASTER=address, FACESCULPT_RUN_DIR=tmp, PYTHONUNBUFFERED="1")
            cap = cv2.VideoCapture(str(_video(name)))
            width, _ = bench_size(int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
            cap.release()
            proc = subprocess.Popen([sys.executable, "-m", "facesculpt.cli", "launch", "coding",
                                     f"camera.source={_video(name)}", f"camera.fps={args.fps}", f"camera.width={width}",
                                     "decoder.window=false", f"decoder.head_motion={args.head_motion}"], env=env, stdout=log, stderr=subprocess.STDOUT)
            out, frames, keys, bases = [], [], [], []
            listener = Node(name=f"_bench_coding_{os.getpid()}", master=address)
            listener.subscribe("render/image", Image, lambda m: out.append((time.time_ns(), m.stamp)), qos=EVERY_MESSAGE)
            listener.subscribe("coding/frame", CodedFrame,
                               lambda m: frames.append((time.time_ns(), sum(len(bytes(f)) for f in encode(m, "coding/frame")),
                                                        m.record.size)), qos=EVERY_MESSAGE)
            listener.subscribe("coding/key", CodedKey, lambda m: keys.append(len(m.header) + m.keyframe.size + m.arrays.size
                                                                             + m.triangles.nbytes), qos=LATCHED)
            listener.subscribe("coding/basis", CodedBasis, lambda m: bases.append(m.arrays.size + m.record.size
                                                                                  + 16 * m.coeff_steps.size),
                               qos=EVERY_MESSAGE)
            listener.start()
            while proc.poll() is None:
                listener.spin_once(0.02)
            listener.close()
            log.seek(0)
            log_tail = log.read()[-2000:]
        if len(out) < 10:
            print(f"| {name} | {args.fps} | no output | | | | | | |\n{log_tail}")
            continue
        # the coded part: from the first decoded frame to the last, without the learning frames
        arrivals = np.array([a for a, _ in out], np.float64)
        rate = (len(out) - 1) / ((arrivals[-1] - arrivals[0]) / 1e9)
        latency = np.array([(a - st) / 1e6 for a, st in out])
        sent = np.array([(a, n) for a, n, _ in frames], np.float64)
        span = (sent[-1, 0] - sent[0, 0]) / 1e9
        wire = sent[:, 1].sum() * 8 / span / 1000
        payload = (sum(n for _, _, n in frames) + sum(keys) + sum(bases)) * 8 / span / 1000
        print(f"| {name} | {args.fps} | {rate:.1f} ({len(out)} of {len(frames)} coded) | {np.percentile(latency, 50):.0f} / "
              f"{np.percentile(latency, 99):.0f} | {wire:.1f} kbit/s ({sent[:, 1].mean():.0f} B a frame) | "
              f"{frames[0][2]} B | {keys[0] if keys else 0} | {len(bases)}: {sum(bases)} | {payload:.1f} kbit/s over {span:.1f} s |")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="what", required=True)
    r = sub.add_parser("reenact")
    r.add_argument("--sources", default="astronaut,d12")
    r.add_argument("--drivers", default="d0,d3,d12")
    r.add_argument("--strips", default="", metavar="DIR")
    c = sub.add_parser("coding")
    c.add_argument("--videos", default="d0,d3,d12")
    c.add_argument("--components", type=int, default=12)
    c.add_argument("--frames", type=int, default=10**6, help="the videos' first N frames only")
    c.add_argument("--body", default="both", choices=("on", "off", "both"),
                   help="the decoder's body motion (issue 51; both: each, on the same stream)")
    c.add_argument("--stills", default="", metavar="DIR", help="write input | body off | body on at 1, 2, 3 s")
    c.add_argument("--no-h264", action="store_true", help="skip the H.264 ladder")
    c.add_argument("--time-reps", type=int, default=0, metavar="N",
                   help="time the decode with the body motion off and on, N alternated passes each")
    g = sub.add_parser("graph")
    g.add_argument("--videos", default="d3,s18")
    g.add_argument("--fps", type=float, default=30.0)
    g.add_argument("--head-motion", default="true", choices=("true", "false"), help="the decoder's head_motion")
    args = p.parse_args()
    if args.what == "graph":
        return bench_graph(args)
    from facesculpt.runtime.process_limits import limit_threads

    limit_threads(1)
    (bench_reenact if args.what == "reenact" else bench_coding)(args)


if __name__ == "__main__":
    main()
