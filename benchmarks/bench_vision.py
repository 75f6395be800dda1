"""Camera pipeline: accuracy on rendered images (2-20 m) and per-frame time at 640x480.

Accuracy study: seeded random views inside the textured room of :mod:`sim.render`, each with
five markers (three coloured discs, two AprilTags 36h11) fully inside the field of view at
random pixels, distances uniform in 2-20 m and normals tilted up to 45 degrees from facing the
camera; observer roll and pitch up to 10 degrees; Gaussian blur (sigma 0.6 px) and pixel noise
(sigma 2 DN); optionally a JPEG round trip. Reports, per kind and distance bin, the detection
rate, the median bearing error (deg), the median and 95th-percentile |range error| (%) and the
false identities (a detection of a vehicle not in view, or more than 2 degrees from its marker).

Timing: median per-frame time of ``VisionPipeline.process`` on 640x480 frames with 5 markers
visible, against a baseline measured in the same run (the bare colour conversion to HSV + grey
that any pipeline pays), and of the pieces (discs only, tags only).

    python benchmarks/bench_vision.py            # 60 images for accuracy, 30 frames timed
    python benchmarks/bench_vision.py --quick    # 12 images
    python benchmarks/bench_vision.py --jpeg --tag-size 1.0
"""

from __future__ import annotations

import argparse
import itertools
import math
import time
from collections.abc import Callable

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


def marker_specs(disc_m: float, tag_m: float) -> list[MarkerSpec]:
    specs = [
        MarkerSpec(i, "disc", disc_m, color_hsv_min=lo, color_hsv_max=hi)
        for i, (_, lo, hi) in DISC_COLOURS.items()
    ]
    return specs + [MarkerSpec(i, "tag", tag_m, family="apriltag_36h11") for i in TAG_IDS]


def random_view(
    renderer: Renderer, rng: np.random.Generator, disc_m: float, tag_m: float
) -> tuple[tuple, list[RenderMarker], dict[int, np.ndarray]]:
    """A seeded observer pose and 5 non-overlapping markers fully in view; truth positions (body)."""
    cam = renderer.camera
    pose = (
        np.array([rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-8, -3)]),
        math.radians(rng.uniform(-10, 10)),
        math.radians(rng.uniform(-10, 10)),
        rng.uniform(-math.pi, math.pi),
    )
    r_ned_body = renderer.camera_pose(*pose)[0] @ cam.r_body_cam.T
    ids = list(DISC_COLOURS) + list(TAG_IDS)
    markers, truth, boxes = [], {}, []
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
        if vid in DISC_COLOURS:
            markers.append(RenderMarker("disc", disc_m, p, rot, color_bgr=DISC_COLOURS[vid][0]))
        else:
            markers.append(RenderMarker("tag", tag_m, p, rot, family="apriltag_36h11", tag_id=vid))
        truth[vid] = r_ned_body.T @ (p - pose[0])
    return pose, markers, truth


def study(
    n_images: int, seed: int, disc_m: float, tag_m: float, jpeg: bool
) -> dict[str, list[tuple[float, bool, float, float]]]:
    cam = CameraModel.from_fov(640, 480, 90.0)
    renderer = Renderer(cam, make_background(seed))
    pipe = VisionPipeline(cam, marker_specs(disc_m, tag_m))
    rng = np.random.default_rng(seed)
    rows: dict[str, list[tuple[float, bool, float, float]]] = {"disc": [], "tag": []}
    false_ids = 0
    for k in range(n_images):
        pose, markers, truth = random_view(renderer, rng, disc_m, tag_m)
        img = renderer.render(*pose, markers, blur_sigma_px=0.6, noise_std=2.0, seed=seed + k)
        if jpeg:
            img = decode_frame(encode_frame(img, "jpeg", 90))
        dets = {d.vehicle_id: d for d in pipe.process(img)}
        for vid, p_body in truth.items():
            rng_true = float(np.linalg.norm(p_body))
            kind = "disc" if vid in DISC_COLOURS else "tag"
            d = dets.get(vid)
            if d is None:
                rows[kind].append((rng_true, False, math.nan, math.nan))
                continue
            err = math.degrees(math.acos(min(1.0, float(d.bearing_body @ p_body) / rng_true)))
            rows[kind].append((rng_true, True, err, 100.0 * (d.range_m - rng_true) / rng_true))
            false_ids += err > 2.0
        false_ids += len(set(dets) - set(truth))
    rows["false_ids"] = [(float(false_ids), True, 0.0, 0.0)]
    return rows


def report(rows: dict[str, list[tuple[float, bool, float, float]]]) -> None:
    print(
        f"{'kind':5s} {'range m':>9s} {'n':>4s} {'detect %':>9s} {'bearing med deg':>16s} "
        f"{'|range err| med %':>18s} {'p95 %':>7s} {'signed med %':>13s}"
    )
    for kind in ("disc", "tag"):
        arr = np.array(rows[kind], dtype=float).reshape(-1, 4)
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
    print(f"false identities: {int(rows['false_ids'][0][0])}")


def median_ms(fun: Callable[[], object], repeats: int) -> float:
    fun()
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fun()
        samples.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(samples))


def timing(n_frames: int, seed: int, disc_m: float, tag_m: float) -> None:
    cam = CameraModel.from_fov(640, 480, 90.0)
    renderer = Renderer(cam, make_background(seed))
    specs = marker_specs(disc_m, tag_m)
    pipe = VisionPipeline(cam, specs)
    discs_only = VisionPipeline(cam, [s for s in specs if s.kind == "disc"])
    tags_only = VisionPipeline(cam, [s for s in specs if s.kind == "tag"])
    rng = np.random.default_rng(seed + 1)
    frames = []
    while len(frames) < n_frames:
        pose, markers, _ = random_view(renderer, rng, disc_m, tag_m)
        if len(markers) == 5:
            frames.append(renderer.render(*pose, markers, blur_sigma_px=0.6, noise_std=2.0))

    def run(fun: Callable[[np.ndarray], object]) -> Callable[[], object]:
        return lambda: [fun(f) for f in frames]

    def baseline(f: np.ndarray) -> object:
        return cv2.cvtColor(f, cv2.COLOR_BGR2HSV), cv2.cvtColor(f, cv2.COLOR_BGR2GRAY)

    base = median_ms(run(baseline), 5) / n_frames
    print(f"\nper-frame time at 640x480, 5 markers visible ({n_frames} frames, median of 5 passes)")
    print(f"{'stage':28s} {'ms/frame':>9s} {'x baseline':>11s}")
    for name, fun in (
        ("baseline: HSV + grey", baseline),
        ("discs only (3 colours)", discs_only.process),
        ("tags only (apriltag_36h11)", tags_only.process),
        ("full pipeline", pipe.process),
    ):
        ms = median_ms(run(fun), 5) / n_frames
        print(f"{name:28s} {ms:9.2f} {ms / base:11.1f}")
    full = median_ms(run(pipe.process), 5) / n_frames
    print(f"target: full pipeline < 10 ms -> {'met' if full < 10.0 else 'NOT met'} ({full:.2f} ms)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--images", type=int, default=60)
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--disc-size", type=float, default=0.5)
    parser.add_argument("--tag-size", type=float, default=0.5)
    parser.add_argument("--jpeg", action="store_true", help="JPEG (q=90) round trip of each image")
    parser.add_argument("--quick", action="store_true")
    args = parser.parse_args()
    n_img = 12 if args.quick else args.images
    print(
        f"accuracy on {n_img} rendered images, discs {args.disc_size} m, tags {args.tag_size} m"
        f"{', JPEG q90' if args.jpeg else ''} (seed {args.seed})"
    )
    report(study(n_img, args.seed, args.disc_size, args.tag_size, args.jpeg))
    timing(10 if args.quick else args.frames, args.seed, args.disc_size, args.tag_size)


if __name__ == "__main__":
    main()
