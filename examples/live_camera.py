"""Run semslam on a live camera through OpenCV, frame by frame, with ``semslam.System``.

Colour comes from ``cv2.VideoCapture`` (BGR, as OpenCV gives it). Depth, where there is
some, comes from the same capture (an OpenNI2 RGB-D camera such as a Kinect or an Astra,
``--openni``: depth in millimetres) or, with no depth camera, from a recorded TUM-layout
folder (``--folder``: colour and depth PNGs read with OpenCV, as a camera would hand them
over, timestamps from rgb.txt). A colour-only camera needs a monocular preset (``--preset
sdf``). Ctrl-C stops after the current frame and writes the outputs.

    python examples/live_camera.py --folder rgbd_dataset_freiburg3_walking_xyz --out run1
    python examples/live_camera.py --openni --camera 570.3,570.3,319.5,239.5 --out run2
    python examples/live_camera.py --device 0 --preset sdf --camera 600,600,320,240 --out run3

The outputs in OUT are those of ``semslam run`` (trajectory.txt, keyframes.txt, stats.json,
the maps in OUT/map/; report.html with --folder when it has groundtruth.txt).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from semslam import System
from semslam.errors import SemslamError
from semslam.runtime import StopOnSignals, limit_threads, stop_requested

Frames = Iterator[tuple[np.ndarray, "np.ndarray | None", float]]


def folder_frames(folder: Path) -> Frames:
    """A recorded RGB-D sequence as a camera would give it: BGR colour, uint16 depth."""
    from semslam.io.association import match_timestamps
    from semslam.io.sequence import read_file_list

    colour, depth = read_file_list(folder / "rgb.txt"), read_file_list(folder / "depth.txt")
    i_colour, i_depth = match_timestamps(np.array([e.timestamp for e in colour]),
                                         np.array([e.timestamp for e in depth]), max_diff=0.02)
    for i, j in sorted(zip(i_colour, i_depth)):  # colour and depth paired as TUM's associate.py does
        bgr = cv2.imread(str(colour[i].path), cv2.IMREAD_COLOR)
        d = cv2.imread(str(depth[j].path), cv2.IMREAD_UNCHANGED)
        if bgr is None or d is None:
            print(f"skipping {colour[i].path}: unreadable colour or depth image", file=sys.stderr)
            continue
        yield bgr, d, colour[i].timestamp


def capture_frames(device: str, openni: bool) -> Frames:
    """Frames of a live capture, stamped with the time they were grabbed."""
    source: int | str = int(device) if device.isdigit() else device
    cap = cv2.VideoCapture(source, cv2.CAP_OPENNI2) if openni else cv2.VideoCapture(source)
    if not cap.isOpened():
        what = "OpenNI2 device (OpenCV built with OpenNI2?)" if openni else "camera"
        raise SystemExit(f"live_camera: cannot open {what} {device!r}")
    try:
        while cap.grab():
            t = time.time()
            if openni:
                ok_c, bgr = cap.retrieve(None, cv2.CAP_OPENNI_BGR_IMAGE)
                ok_d, depth = cap.retrieve(None, cv2.CAP_OPENNI_DEPTH_MAP)  # uint16 millimetres
                if ok_c and ok_d:
                    yield bgr, depth, t
            else:
                ok, bgr = cap.retrieve()
                if ok:
                    yield bgr, None, t
    finally:
        cap.release()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--folder", type=Path, help="TUM-layout RGB-D folder standing in for a depth camera")
    src.add_argument("--device", help="cv2.VideoCapture source: a device index (0) or a video file / URL")
    src.add_argument("--openni", action="store_true", help="an OpenNI2 RGB-D camera (colour + depth in mm)")
    ap.add_argument("--camera", help="fx,fy,cx,cy[,k1,k2,p1,p2,k3] (default: the folder's calib.txt / name)")
    ap.add_argument("--preset", default="default", help="semslam preset (colour only: sdf)")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                    help="config override, as semslam run --set")
    ap.add_argument("--out", type=Path, required=True, help="output folder")
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--show", action="store_true", help="show the colour image in a window (q quits)")
    args = ap.parse_args(argv)

    limit_threads()  # one BLAS / OpenCV thread: SLAM runs threads of its own
    camera: list[float] | Path
    if args.camera:
        camera = [float(v) for v in args.camera.split(",")]
    elif args.folder is not None:
        camera = args.folder
    else:
        ap.error("--camera fx,fy,cx,cy is needed for a live camera")
    if args.folder is not None:  # its depth PNGs: TUM's 5000 units per metre, the presets' depth_scale
        frames = folder_frames(args.folder)
    else:
        frames = capture_frames("0" if args.openni else args.device, args.openni)
    gt = args.folder / "groundtruth.txt" if args.folder is not None else None
    try:
        with StopOnSignals(), System(args.preset, camera, bgr=True, overrides=args.overrides,
                                     depth_scale=1000.0 if args.openni else None) as slam:
            for n, (bgr, depth, t) in enumerate(frames):
                if stop_requested() or (args.max_frames is not None and n >= args.max_frames):
                    break
                result = slam.track(bgr, depth, t)
                if n % 30 == 0:
                    where = "lost" if result.pose_wc is None else np.array2string(result.pose_wc[:3, 3], precision=3)
                    print(f"frame {n}: {result.state.value}, position {where}, {slam.n_keyframes} keyframes")
                if args.show:
                    cv2.imshow("semslam", bgr)
                    if cv2.waitKey(1) & 0xFF == ord("q"):
                        break
            result_all = slam.save(args.out, groundtruth=gt if gt is not None and gt.is_file() else None)
    except SemslamError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    ate = f", ATE {result_all.ate_rmse * 100:.2f} cm" if result_all.ate_rmse is not None else ""
    print(f"{result_all.tracked_frames}/{result_all.frames} frames tracked, {result_all.keyframes} keyframes{ate}; "
          f"outputs in {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
