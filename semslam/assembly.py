"""What a run is made of, built from its config: the depth source, the dynamic stage, the
maps' worker and the tracker named by ``tracking.method`` (through the registry).

``semslam.System`` builds these parts here and runs them; which tracker runs is
configuration (adding one is a module with a ``create_tracker`` factory plus a registry
line). The tracker is handed only what ``core.protocols.TrackerInputs`` holds: it never sees
the map builders, the System feeds them from the tracker's results.
"""

from __future__ import annotations

import logging

from dataclasses import dataclass
from pathlib import Path

from semslam.config import SystemConfig
from semslam.core import registry
from semslam.core.imu import ImuCalibration
from semslam.core.protocols import DepthSource, DynamicStage, MapStage, Tracker, TrackerInputs
from semslam.dynamics.stage import create_dynamic_stage
from semslam.errors import ConfigError
from semslam.features.jit import warm_up as warm_up_kernels
from semslam.frontend.stereo_depth import StereoDepth
from semslam.geometry.camera import PinholeCamera
from semslam.slam.orb.frame_builders import is_monocular

log = logging.getLogger(__name__)


@dataclass
class RunParts:
    """The parts of one run; ``semslam.System`` owns them (and closes them)."""

    depth: DepthSource
    dynamics: DynamicStage | None
    maps: MapStage | None
    tracker: Tracker
    #: Seconds spent building (or loading) the compiled kernels before the first frame.
    jit_warmup_s: float
    #: A stereo run's dense depth from the pair (None: not a stereo run, or nothing reads it).
    stereo_depth: StereoDepth | None = None


def wants_stereo_depth(config: SystemConfig) -> bool:
    """Whether a stereo run needs a depth image (``depth.stereo_dense``): ``auto`` when a part
    that reads one is on (the semantic stage's SRM and mask warping, the multi-view check,
    depth odometry, the rolling-shutter correction, inpainting and the maps)."""
    if config.sensor != "stereo" or config.depth.stereo_dense == "never":
        return False
    if config.depth.stereo_dense == "always":
        return True
    slam = config.slam
    return bool(config.dynamics.semantic or config.dynamics.multiview or config.maps.builders
                or config.maps.save_inpainted or slam.depth_odometry != "none" or slam.rolling_shutter_ms > 0)


def pair_depth(config: SystemConfig, camera: PinholeCamera) -> StereoDepth:
    """The dense depth a stereo run computes from its pair (``depth.stereo_downscale``)."""
    return StereoDepth(config.slam.bf, camera.width, camera.height, downscale=config.depth.stereo_downscale)


def check_sensor(config: SystemConfig) -> None:
    """A stereo run's depth comes from the pair: refuse a depth network as its source."""
    if config.sensor == "stereo" and config.depth.source != "sensor":
        raise ConfigError(f"depth.source: {config.depth.source} with sensor: stereo; a stereo camera's depth comes "
                          "from the pair (depth.source: sensor)")


def create_map_stage(config: SystemConfig) -> MapStage | None:
    """Inpainting and every builder of ``maps.builders`` in the maps' own worker; None without maps."""
    if not config.maps.builders:
        return None
    from semslam.reconstruction.mapping_worker import MappingWorker

    # The worker segments keyframes tracking did not (a backend that reads its labels from the
    # sequence, ground_truth, needs the frame's files: not from a snapshot).
    segment = (config.maps.segment_keyframes and config.dynamics.semantic
               and config.semantics.backend != "ground_truth")
    return MappingWorker(config.maps.builders, config.maps, threaded=not config.slam.sequential,
                         inpainted_dir=Path(config.maps.save_inpainted) if config.maps.save_inpainted else None,
                         semantics=config.semantics if segment else None)


def usable_imu(config: SystemConfig, imu: ImuCalibration | None) -> ImuCalibration | None:
    """The IMU's calibration where tracking uses it: the ORB core with stereo, RGB-D or
    monocular geometry (the map's scale then from the IMU); else None, with a warning when the
    input has one."""
    if imu is None or not config.imu.use:
        return None
    pseudo_rgbd = config.sensor == "mono" and not is_monocular(config)
    if config.tracking.method != "orb_slam" or pseudo_rgbd:
        what = ("a depth network's depth sets the monocular map's scale (depth.use: prior lets the IMU set it)"
                if pseudo_rgbd else f"tracking.method {config.tracking.method} does not use one")
        log.warning("the input has an IMU, but %s: it is ignored (imu.use=false silences this)", what)
        return None
    return imu


def assemble(config: SystemConfig, camera: PinholeCamera, map_path: Path | None = None,
             imu: ImuCalibration | None = None) -> RunParts:
    """Every part of the run; what was built is closed again when a later part fails.
    ``imu``: the IMU's calibration when the input has one (unused with ``imu.use: false``)."""
    check_sensor(config)
    create_tracker = registry.load("tracker", config.tracking.method)
    # Compiled kernels are built (or loaded from disk) now, not inside the first frames.
    kernels = ("semslam.dynamics.multiview_kernels", "semslam.slam.orb.row_kernels")
    if config.sensor == "stereo":
        kernels += ("semslam.slam.orb.stereo_matching",)
    jit_warmup_s = warm_up_kernels(kernels)
    depth: DepthSource = registry.create("depth_source", config.depth.source, config.depth.resolved(config.semantics))
    maps = create_map_stage(config)
    dynamics = None
    try:
        # A depth network (no sensor depth) is what SRM and the mask warp read.
        dynamics = create_dynamic_stage(config.dynamics, config.semantics, camera,
                                        threaded=not config.slam.sequential,
                                        depth=depth if config.depth.source != "sensor" else None)
        inputs = TrackerInputs(depth, dynamics, usable_imu(config, imu))
        tracker: Tracker = create_tracker(config, camera, inputs, map_path)
    except BaseException:
        if maps is not None:
            maps.close()
        if dynamics is not None:
            dynamics.close()
        raise
    stereo_depth = pair_depth(config, camera) if wants_stereo_depth(config) else None
    return RunParts(depth, dynamics, maps, tracker, jit_warmup_s, stereo_depth)
