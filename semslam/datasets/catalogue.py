"""The catalogue: every public RGB-D sequence ``semslam dataset get`` knows, by name.

One data table per dataset (name, archive URL, archive type, folder name inside), turned
into :class:`DatasetEntry` rows. Names are ``family/short``: ``tum/fr3_walking_xyz``,
``bonn/balloon``, ``icl/lr_kt0``. Each sequence is extracted to a folder named as its
publisher names it (``rgbd_dataset_freiburg3_walking_xyz``, ``rgbd_bonn_balloon``,
``living_room_traj0_frei_png``), because ``io/calibration.py`` recognises the camera from
that name.

Sources of the URLs (checked against public download scripts, see the README section):
TUM RGB-D https://cvg.cit.tum.de/data/datasets/rgbd-dataset/download, Bonn RGB-D Dynamic
https://www.ipb.uni-bonn.de/data/rgbd-dynamic-dataset/, ICL-NUIM's TUM-format release
https://www.doc.ic.ac.uk/~ahanda/VaFRIC/iclnuim.html. None of them publishes checksums,
so ``sha256`` is empty and a download is verified by its size and by its content.
"""

from __future__ import annotations

from dataclasses import dataclass

TUM_BASE = "https://cvg.cit.tum.de/rgbd/dataset"
BONN_BASE = "https://www.ipb.uni-bonn.de/html/projects/rgbd_dynamic2019"
ICL_BASE = "https://www.doc.ic.ac.uk/~ahanda"

# The files a TUM-layout folder needs (io/sequence.py reads them).
TUM_FILES = ("rgb.txt", "depth.txt", "groundtruth.txt")
# ICL-NUIM's TUM-format tarballs: an associations file and ``<name>.gt.freiburg``, no lists.
ICL_FILES = ("associations.txt", "*.gt.freiburg")


@dataclass(frozen=True)
class DatasetEntry:
    """One downloadable sequence.

    ``inner`` is the folder the archive holds the sequence in (``None``: the files lie at
    the archive's top level, as in ICL-NUIM's tarballs); ``folder`` is the folder it is
    extracted to under the data directory; ``required`` are file names (globs) that must be
    in it for the download to count as complete.
    """

    name: str
    url: str
    archive: str  # "tgz" | "zip"
    folder: str
    inner: str | None
    required: tuple[str, ...]
    sha256: str | None = None
    description: str = ""

    @property
    def family(self) -> str:
        return self.name.split("/", 1)[0]

    @property
    def filename(self) -> str:
        """The archive's file name as published (also its name on a mirror)."""
        return self.url.rsplit("/", 1)[-1]


# ---------------------------------------------------------------------------- TUM RGB-D
# (freiburg number, sequence) in the order of TUM's download page; the validation and
# calibration sequences (no public ground truth) are left out.
_TUM: tuple[tuple[int, str], ...] = (
    # Testing and debugging
    (1, "xyz"), (1, "rpy"), (2, "xyz"), (2, "rpy"),
    # Handheld SLAM
    (1, "360"), (1, "floor"), (1, "desk"), (1, "desk2"), (1, "room"),
    (2, "360_hemisphere"), (2, "360_kidnap"), (2, "desk"), (2, "large_no_loop"),
    (2, "large_with_loop"), (3, "long_office_household"),
    # Robot SLAM
    (2, "pioneer_360"), (2, "pioneer_slam"), (2, "pioneer_slam2"), (2, "pioneer_slam3"),
    # Structure vs. texture
    (3, "nostructure_notexture_far"), (3, "nostructure_notexture_near_withloop"),
    (3, "nostructure_texture_far"), (3, "nostructure_texture_near_withloop"),
    (3, "structure_notexture_far"), (3, "structure_notexture_near"),
    (3, "structure_texture_far"), (3, "structure_texture_near"),
    # Dynamic objects
    (2, "desk_with_person"), (3, "sitting_static"), (3, "sitting_xyz"),
    (3, "sitting_halfsphere"), (3, "sitting_rpy"), (3, "walking_static"),
    (3, "walking_xyz"), (3, "walking_halfsphere"), (3, "walking_rpy"),
    # 3D object reconstruction
    (1, "plant"), (1, "teddy"), (2, "coke"), (2, "dishes"), (2, "flowerbouquet"),
    (2, "flowerbouquet_brownbackground"), (2, "metallic_sphere"), (2, "metallic_sphere2"),
    (3, "cabinet"), (3, "large_cabinet"), (3, "teddy"),
)

# ---------------------------------------------------------------------------- Bonn RGB-D Dynamic
_BONN: tuple[str, ...] = (
    "balloon", "balloon2", "balloon_tracking", "balloon_tracking2", "crowd", "crowd2",
    "crowd3", "kidnapping_box", "kidnapping_box2", "moving_nonobstructing_box",
    "moving_nonobstructing_box2", "moving_obstructing_box", "moving_obstructing_box2",
    "person_tracking", "person_tracking2", "placing_nonobstructing_box",
    "placing_nonobstructing_box2", "placing_nonobstructing_box3", "placing_obstructing_box",
    "removing_nonobstructing_box", "removing_nonobstructing_box2", "removing_obstructing_box",
    "static", "static_close_far", "synchronous", "synchronous2",
)

# ---------------------------------------------------------------------------- ICL-NUIM (TUM format)
# (short name, archive stem, folder). The office room's archives are published as
# ``trajN_frei_png``; the folder says ``office_room`` so that the calibration is recognised.
_ICL: tuple[tuple[str, str, str], ...] = tuple(
    (f"lr_kt{i}", f"living_room_traj{i}_frei_png", f"living_room_traj{i}_frei_png") for i in range(4)
) + tuple(
    (f"of_kt{i}", f"traj{i}_frei_png", f"office_room_traj{i}_frei_png") for i in range(4)
)


def _build() -> dict[str, DatasetEntry]:
    rows: list[DatasetEntry] = []
    for fr, seq in _TUM:
        folder = f"rgbd_dataset_freiburg{fr}_{seq}"
        rows.append(DatasetEntry(f"tum/fr{fr}_{seq}", f"{TUM_BASE}/freiburg{fr}/{folder}.tgz", "tgz",
                                 folder, folder, TUM_FILES, description=f"TUM RGB-D freiburg{fr}_{seq}"))
    for seq in _BONN:
        folder = f"rgbd_bonn_{seq}"
        rows.append(DatasetEntry(f"bonn/{seq}", f"{BONN_BASE}/{folder}.zip", "zip", folder, folder, TUM_FILES,
                                 description=f"Bonn RGB-D Dynamic {seq}"))
    for short, stem, folder in _ICL:
        rows.append(DatasetEntry(f"icl/{short}", f"{ICL_BASE}/{stem}.tar.gz", "tgz", folder, None, ICL_FILES,
                                 description=f"ICL-NUIM {folder} (TUM format)"))
    return {r.name: r for r in rows}


CATALOGUE: dict[str, DatasetEntry] = _build()
FAMILIES = ("tum", "bonn", "icl")
