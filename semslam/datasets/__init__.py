"""Public RGB-D sequences by name: the catalogue, downloading and the local data folder.

``semslam dataset get tum/fr3_walking_xyz`` downloads (resuming), verifies and extracts a
sequence; ``semslam run tum/fr3_walking_xyz`` then finds it through :func:`resolve`.
"""

from semslam.datasets.catalogue import CATALOGUE, FAMILIES, DatasetEntry
from semslam.datasets.download import DownloadError
from semslam.datasets.store import archive_url, data_dir, get, is_dataset_name, is_downloaded, lookup, resolve

__all__ = [
    "CATALOGUE",
    "FAMILIES",
    "DatasetEntry",
    "DownloadError",
    "archive_url",
    "data_dir",
    "get",
    "is_dataset_name",
    "is_downloaded",
    "lookup",
    "resolve",
]
