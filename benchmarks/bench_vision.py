"""Camera pipeline: accuracy and detection rate on rendered images (2-20 m), per-frame time.

Accuracy study: seeded random views inside the textured room of :mod:`sim.render`, each with
five markers (three coloured discs, two AprilTags 36h11) fully inside the field of view at
random pixels, distances uniform in 2-20 m and normals tilted up to 45 degrees from facing the
camera; observer roll and pitch up to 10 degrees; Gaussian blur (sigma 0.6 px) and pixel noise
(sigma 2 DN); optionally a JPEG round trip and a contrast reduction. Reports, per kind and
distance bin, the detection rate, the median bearing error (deg), the median and 95th-percentile
|range error| (%) and the false identities (a detection of a vehicle not in view, or more than
2 degrees from its marker). Tags are also counted among the *resolvable* ones: the shortest side
of the black square at least 14 px in the image (1.75 px per cell for 36h11); smaller tags
cannot be decoded at any setting (0.5 m tags beyond about 11 m at 640x480 / 90 degrees).

Timing: 640x480 frames with 5 markers visible; every method runs on every frame, interleaved
frame by frame (so machine load hits all alike), and the median per-frame time is reported
with its ratio to two baselines measured in the same run: the plain OpenCV detector
(``cv2.aruco.ArucoDetector`` with default parameters and the full apriltag_36h11 dictionary,
on the grey frame: what "just call detectMarkers" costs, tags only) and the bare colour
conversions (HSV + grey) that any colour pipeline pays. The machine may be shared: the load
average (``os.getloadavg``) before and after the timing, and OpenCV's thread count, are printed
with the absolute numbers.

    python benchmarks/bench_vision.py            # 60 images for accuracy, 30 frames timed
    python benchmarks/bench_vision.py --quick    # 12 images, 10 frames
    python benchmarks/bench_vision.py --jpeg --tag-size 1.0 --contrast 0.5
    python benchmarks/bench_vision.py --quick --threads 1   # cv2.setNumThreads(1) first
"""

from __future__ import annotations

import argparse
import itertools
import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from messages.image import decode_frame, encode_frame
from onboard.vision.camera import CameraModel
from onboard.vision.markers import MarkerSpec
from onboard.vision.pipeline import VisionPipeline
from sim.render import Renderer, RenderMarker, make_background, place_in_view

DISC_COLOURS = {  # vehicle id -> (BGR fill, HSV min, HSV max)
    1: ((0, 0, 220), (170, 120, 60), (10, 255, 255)),
    2: ((0, 200, 0), (50, 120, 60), (70, 255, 255)),
    3: ((220, 90, 0), (100, 120, 60), (125, 255, 255)),
}
TAG_IDS = (4, 5)
BINS_M = (2.0, 5.0, 10.0, 15.0, 20.0)
RESOLVABLE_TAG_SIDE_PX = 14.0


def marker_specs(disc_m: float, tag_m: float) -> list[MarkerSpec]:
    specs = [
        MarkerSpec(i, "disc", disc_m, color_hsv_min=lo, color_hsv_max=hi)
        for i, (_, lo, hi) in DISC_COLOURS.items()
    ]
    return specs + [MarkerSpec(i, "tag", tag_m, family="apriltag_36h11") for i in TAG_IDS]


@dataclass(frozen=True)
class View:
    """One random scene: observer pose, markers, and the truth the study compares with."""

    pose: tuple
    markers: list[RenderMarker]
    p_body: dict[int, np.ndarray]
    """Marker centres in the observer's body frame (m)."""
    min_side_px: dict[int, float]
    """Shortest image side of each marker's square (tags: the black square; discs: the
    bounding square of the disc)."""


def random_view(renderer: Renderer, rng: np.random.Generator, disc_m: float, tag_m: float) -> View:
    """A seeded observer pose and 5 non-overlapping markers fully in view, with their truth."""
    cam = renderer.camera
    pose = (
        np.array([rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-8, -3)]),
        math.radians(rng.uniform(-10, 10)),
        math.radians(rng.uniform(-10, 10)),
        rng.uniform(-math.pi, math.pi),
    )
    r_ned_cam, c_ned = renderer.camera_pose(*pose)
    r_ned_body = r_ned_cam @ cam.r_body_cam.T
    ids = list(DISC_COLOURS) + list(TAG_IDS)
    markers, truth, sides, boxes = [], {}, {}, []
    for vid in ids:
        size = disc_m if vid in DISC_COLOURS else tag_m * 1.25
        for _ in range(200):
            d = rng.uniform(2.0, 20.0)
            r_px = 0.75 * size * cam.fx / d + 3  # generous radius incl. tilt and quiet zone
            uv = rng.uniform([r_px, r_px], [cam.width - r_px, cam.height - r_px])
            if r_px * 2 < min(cam.width, cam.height) and all(
                np.hypot(*(uv - b[:2])) > r_px + b[2] for b in boxes
            ):
                break
        else:
            continue
        boxes.append(np.array([uv[0], uv[1], r_px]))
        p, rot = place_in_view(
            renderer, pose, uv, d, math.radians(rng.uniform(0, 45)), rng.uniform(0, 2 * np.pi)
        )
        m_size = disc_m if vid in DISC_COLOURS else tag_m
        if vid in DISC_COLOURS:
            markers.append(RenderMarker("disc", disc_m, p, rot, color_bgr=DISC_COLOURS[vid][0]))
        else:
            markers.append(RenderMarker("tag", tag_m, p, rot, family="apriltag_36h11", tag_id=vid))
        truth[vid] = r_ned_body.T @ (p - pose[0])
        square = 0.5 * m_size * np.array([[-1, 1], [1, 1], [1, -1], [-1, -1]], dtype=float)
        corners_uv, _ = cam.project_cam((p + square @ rot[:, :2].T - c_ned) @ r_ned_cam)
        sides[vid] = float(np.min(np.linalg.norm(np.roll(corners_uv, -1, 0) - corners_uv, axis=1)))
    return View(pose, markers, truth, sides)


Row = tuple[float, bool, float, float, float]
"""(true range m, detected, bearing error deg, signed range error %, shortest side px)"""


def study(
    n_images: int, seed: int, disc_m: float, tag_m: float, jpeg: bool, contrast: float = 1.0
) -> tuple[dict[str, list[Row]], int]:
    """Rows per kind and the number of false identities over ``n_images`` seeded views."""
    cam = CameraModel.from_fov(640, 480, 90.0)
    renderer = Renderer(cam, make_background(seed))
    pipe = VisionPipeline(cam, marker_specs(disc_m, tag_m))
    rng = np.random.default_rng(seed)
    rows: dict[str, list[Row]] = {"disc": [], "tag": []}
    false_ids = 0
    for k in range(n_images):
        view = random_view(renderer, rng, disc_m, tag_m)
        img = renderer.render(
            *view.pose, view.markers, blur_sigma_px=0.6, noise_std=2.0, seed=seed + k
        )
        if contrast != 1.0:
            img = np.clip(contrast * (img.astype(float) - 128.0) + 128.0, 0, 255).astype(np.uint8)
        if jpeg:
            img = decode_frame(encode_frame(img, "jpeg", 90, full_chroma=False))
        dets = {d.vehicle_id: d for d in pipe.process(img)}
        for vid, p_body in view.p_body.items():
            rng_true = float(np.linalg.norm(p_body))
            kind = "disc" if vid in DISC_COLOURS else "tag"
            side = view.min_side_px[vid]
            d = dets.get(vid)
            if d is None:
                rows[kind].append((rng_true, False, math.nan, math.nan, side))
                continue
            err = math.degrees(math.acos(min(1.0, float(d.bearing_body @ p_body) / rng_true)))
            rows[kind].append(
                (rng_true, True, err, 100.0 * (d.range_m - rng_true) / rng_true, side)
            )
            false_ids += err > 2.0
        false_ids += len(set(dets) - set(view.p_body))
    return rows, false_ids


def report(rows: dict[str, list[Row]], false_ids: int) -> None:
    print(
        f"{'kind':5s} {'range m':>9s} {'n':>4s} {'detect %':>9s} {'bearing med deg':>16s} "
        f"{'|range err| med %':>18s} {'p95 %':>7s} {'signed med %':>13s}"
    )
    for kind in ("disc", "tag"):
        arr = np.array(rows[kind], dtype=float).reshape(-1, 5)
        for lo, hi in itertools.pairwise(BINS_M):
            sel = arr[(arr[:, 0] >= lo) & (arr[:, 0] < hi)]
            if sel.size == 0:
                continue
            det = sel[sel[:, 1] > 0]
            rate = 100.0 * len(det) / len(sel)
            be = np.median(det[:, 2]) if len(det) else math.nan
            re = np.median(np.abs(det[:, 3])) if len(det) else math.nan
            p95 = np.percentile(np.abs(det[:, 3]), 95) if len(det) else math.nan
            sg = np.median(det[:, 3]) if len(det) else math.nan
            print(
                f"{kind:5s} {lo:4.0f}-{hi:<4.0f} {len(sel):4d} {rate:9.1f} {be:16.3f} "
                f"{re:18.2f} {p95:7.2f} {sg:13.2f}"
            )
    print("detection rate, markers fully inside the field of view:")
    for kind in ("disc", "tag"):
        arr = np.array(rows[kind], dtype=float).reshape(-1, 5)
        print(f"  {kind}s, all 2-20 m: {100.0 * arr[:, 1].mean():5.1f} % of {len(arr)}")
    tags = np.array(rows["tag"], dtype=float).reshape(-1, 5)
    ok = tags[tags[:, 4] >= RESOLVABLE_TAG_SIDE_PX]
    if len(ok):
        print(
            f"  tags, resolvable (shortest side >= {RESOLVABLE_TAG_SIDE_PX:.0f} px): "
            f"{100.0 * ok[:, 1].mean():5.1f} % of {len(ok)}"
        )
    print(f"false identities: {false_ids}")


def timed_frames(n_frames: int, seed: int, disc_m: float, tag_m: float) -> list[np.ndarray]:
    cam = CameraModel.from_fov(640, 480, 90.0)
    renderer = Renderer(cam, make_background(seed))
    rng = np.random.default_rng(seed + 1)
    frames = []
    while len(frames) < n_frames:
        view = random_view(renderer, rng, disc_m, tag_m)
        if len(view.markers) == 5:
            frames.append(
                renderer.render(*view.pose, view.markers, blur_sigma_px=0.6, noise_std=2.0)
            )
    return frames


def interleaved_medians_ms(
    methods: dict[str, Callable[[np.ndarray], object]], frames: list[np.ndarray], passes: int
) -> dict[str, float]:
    """Median per-frame time (ms) of each method; all methods run on a frame before the next."""
    samples: dict[str, list[float]] = {name: [] for name in methods}
    for f in frames[:2]:  # warm-up
        for fun in methods.values():
            fun(f)
    for _ in range(passes):
        for f in frames:
            for name, fun in methods.items():
                t0 = time.perf_counter()
                fun(f)
                samples[name].append(time.perf_counter() - t0)
    return {name: 1e3 * float(np.median(v)) for name, v in samples.items()}


def timing(n_frames: int, passes: int, seed: int, disc_m: float, tag_m: float) -> None:
    cam = CameraModel.from_fov(640, 480, 90.0)
    frames = timed_frames(n_frames, seed, disc_m, tag_m)
    specs = marker_specs(disc_m, tag_m)
    pipe = VisionPipeline(cam, specs)
    discs_only = VisionPipeline(cam, [s for s in specs if s.kind == "disc"])
    tags_only = VisionPipeline(cam, [s for s in specs if s.kind == "tag"])
    plain = cv2.aruco.ArucoDetector(
        cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11),
        cv2.aruco.DetectorParameters(),
    )
    grey = {id(f): cv2.cvtColor(f, cv2.COLOR_BGR2GRAY) for f in frames}

    def conversions(f: np.ndarray) -> object:
        return cv2.cvtColor(f, cv2.COLOR_BGR2HSV), cv2.cvtColor(f, cv2.COLOR_BGR2GRAY)

    methods: dict[str, Callable[[np.ndarray], object]] = {
        "baseline A: cv2 detectMarkers": lambda f: plain.detectMarkers(grey[id(f)]),
        "baseline B: HSV + grey": conversions,
        "discs only (3 colours)": discs_only.process,
        "tags only (apriltag_36h11)": tags_only.process,
        "full pipeline (5 markers)": pipe.process,
    }
    load0 = os.getloadavg()
    ms = interleaved_medians_ms(methods, frames, passes)
    load1 = os.getloadavg()
    base_a = ms["baseline A: cv2 detectMarkers"]
    base_b = ms["baseline B: HSV + grey"]
    print(
        f"\nper-frame time at 640x480, 5 markers visible ({n_frames} frames x {passes} passes,"
        f" interleaved; OpenCV {cv2.__version__}, {cv2.getNumThreads()} threads, "
        f"{os.cpu_count()} CPUs)"
    )
    print(
        f"load average (1, 5, 15 min): before {load0[0]:.2f} {load0[1]:.2f} {load0[2]:.2f}, "
        f"after {load1[0]:.2f} {load1[1]:.2f} {load1[2]:.2f}"
    )
    print(f"{'stage':30s} {'median ms':>10s} {'/ A':>7s} {'/ B':>7s}")
    for name, value in ms.items():
        print(f"{name:30s} {value:10.2f} {value / base_a:7.2f} {value / base_b:7.2f}")
    full = ms["full pipeline (5 markers)"]
    print(
        f"target: full pipeline < 10 ms median -> {'met' if full < 10.0 else 'NOT met'} "
        f"({full:.2f} ms at load {load1[0]:.2f})"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--images", type=int, default=60)
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--passes", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--disc-size", type=float, default=0.5)
    parser.add_argument("--tag-size", type=float, default=0.5)
    parser.add_argument(
        "--jpeg",
        action="store_true",
        help="JPEG (q=90, 4:2:0 chroma like a video stream) round trip of each image",
    )
    parser.add_argument(
        "--contrast", type=float, default=1.0, help="scale grey levels about 128 (e.g. 0.5)"
    )
    parser.add_argument("--no-timing", action="store_true")
    parser.add_argument(
        "--threads",
        type=int,
        default=None,
        help="cv2.setNumThreads before timing (default: OpenCV's)",
    )
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    n_img = 12 if args.quick else args.images
    print(
        f"accuracy on {n_img} rendered images, discs {args.disc_size} m, tags {args.tag_size} m"
        f"{', JPEG q90' if args.jpeg else ''}"
        f"{f', contrast x{args.contrast}' if args.contrast != 1.0 else ''} (seed {args.seed})"
    )
    report(*study(n_img, args.seed, args.disc_size, args.tag_size, args.jpeg, args.contrast))
    if not args.no_timing:
        if args.threads is not None:
            cv2.setNumThreads(args.threads)
        n_frames = 10 if args.quick else args.frames
        timing(n_frames, 3 if args.quick else args.passes, args.seed, args.disc_size, args.tag_size)


if __name__ == "__main__":
    main()
