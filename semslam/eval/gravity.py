"""How far a trajectory's world is from gravity-aligned: the tilt between its -z axis and
the reference's gravity (also -z: EuRoC's, TUM's and semslam's renders' worlds are z-up).

The two worlds are related by the mean of the associated frames' orientation differences
(``R_ref_i @ R_est_i^T``) rather than by evo's Umeyama alignment: on a short or straight path
the positions pin that rotation far less well than the orientations do, and gravity is a
statement about orientation.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from semslam.core.trajectory import Trajectory
from semslam.errors import EvalError
from semslam.io.association import associate


def gravity_tilt_deg(reference: Trajectory, estimate: Trajectory, max_diff: float = 0.02) -> float:
    """Degrees between ``estimate``'s -z and ``reference``'s -z (gravity), the worlds related
    by the frames' mean orientation difference."""
    i_ref, i_est = associate(reference.timestamps, estimate.timestamps, max_diff)
    if len(i_ref) == 0:
        raise EvalError(f"{estimate.name or 'the estimate'}: no timestamps match the reference's")
    turns = reference.poses[i_ref, :3, :3] @ np.transpose(estimate.poses[i_est, :3, :3], (0, 2, 1))
    down = Rotation.from_matrix(turns).mean().apply([0.0, 0.0, -1.0])  # the estimate's -z in the reference
    return float(np.degrees(np.arccos(np.clip(-down[2], -1.0, 1.0))))
