"""``bearingflock vision probe IMAGE --camera CAMERA.toml``: run the marker pipeline on one image.

Prints one line per detection (or, with ``--json``, a JSON list of objects with ``id, kind,
bearing_body, range_m, quality, center_px``), and with ``--draw OUT.png`` writes the image with
the fitted outlines and ids drawn. Without ``--markers`` every ``apriltag_36h11`` tag is reported
with its tag id as the vehicle id and no range (``null``: the tag size is unknown).
A bad image or configuration file prints a one-line error and exits with status 2.
"""

from __future__ import annotations

import json as jsonlib
import sys
from pathlib import Path
from typing import Annotated

import typer

EXIT_OK, EXIT_INVALID = 0, 2

vision_app = typer.Typer(
    name="vision",
    help="The onboard camera pipeline: marker bearings and ranges from images.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


@vision_app.callback()
def _vision() -> None:
    """The onboard camera pipeline: marker bearings and ranges from images."""


def _fail(message: str) -> typer.Exit:
    sys.stderr.write(f"error: {message}\n")
    return typer.Exit(EXIT_INVALID)


@vision_app.command("probe")
def probe(
    image: Annotated[
        Path, typer.Argument(help="Image file (PNG, JPEG, ... anything cv2.imread reads).")
    ],
    camera: Annotated[
        Path, typer.Option("--camera", help="Camera file (TOML), see docs/vision.md.")
    ],
    markers: Annotated[
        Path | None, typer.Option("--markers", help="Markers file (TOML), see docs/vision.md.")
    ] = None,
    json: Annotated[
        bool, typer.Option("--json", help="Print the detections as a JSON list.")
    ] = False,
    draw: Annotated[
        Path | None, typer.Option("--draw", help="Write the image with the detections drawn.")
    ] = None,
) -> None:
    """Detect the markers in IMAGE and print their ids, body-frame bearings and ranges."""
    import math

    import cv2
    import numpy as np

    from messages.image import FrameError, decode_frame
    from onboard.vision.config import VisionConfigError, load_camera, load_markers
    from onboard.vision.markers import MarkerSpec
    from onboard.vision.pipeline import VisionPipeline

    try:
        cam = load_camera(camera)
        if markers is not None:
            specs = load_markers(markers)
            unknown_range = False
        else:
            # no markers file: all 587 apriltag_36h11 ids, size 1 m (range reported as unknown)
            specs = [MarkerSpec(i, "tag", 1.0) for i in range(587)]
            unknown_range = True
    except VisionConfigError as exc:
        raise _fail(str(exc)) from None
    try:
        data = image.read_bytes()
    except OSError as exc:
        raise _fail(f"{image}: cannot read ({exc.strerror})") from None
    try:
        frame = decode_frame(data, cam.width, cam.height)
        if frame.ndim == 3 and frame.shape[2] == 1:
            frame = frame[:, :, 0]
        detections = VisionPipeline(cam, specs).process(frame)
    except FrameError as exc:
        raise _fail(f"{image}: {exc}") from None
    rows = [d.to_json() for d in detections]
    if unknown_range:
        for r in rows:
            r["range_m"] = None
    if json:
        sys.stdout.write(jsonlib.dumps(rows) + "\n")
    else:
        if not rows:
            sys.stdout.write("no markers detected\n")
        for r in rows:
            b = r["bearing_body"]
            az = math.degrees(math.atan2(b[1], b[0]))
            el = -math.degrees(math.asin(max(-1.0, min(1.0, b[2]))))
            rng = "?" if r["range_m"] is None else f"{r['range_m']:.2f} m"
            sys.stdout.write(
                f"id {r['id']:3d} {r['kind']:4s} bearing_body ({b[0]:+.4f}, {b[1]:+.4f}, {b[2]:+.4f})"
                f"  azimuth {az:+7.2f} deg  elevation {el:+6.2f} deg  range {rng}"
                f"  quality {r['quality']:.2f}\n"
            )
    if draw is not None:
        canvas = cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR) if frame.ndim == 2 else frame.copy()
        for d in detections:
            pts = np.round(d.outline_px).astype(np.int32).reshape(-1, 1, 2)
            cv2.polylines(canvas, [pts], True, (0, 255, 255), 1, cv2.LINE_AA)
            u, v = (round(x) for x in d.center_px)
            cv2.drawMarker(canvas, (u, v), (0, 255, 255), cv2.MARKER_CROSS, 8, 1)
            cv2.putText(
                canvas,
                str(d.vehicle_id),
                (u + 6, v - 6),
                cv2.FONT_HERSHEY_SIMPLEX,
                0.5,
                (0, 255, 255),
                1,
                cv2.LINE_AA,
            )
        if not cv2.imwrite(str(draw), canvas):
            raise _fail(f"{draw}: cannot write the image")
    raise typer.Exit(EXIT_OK)
