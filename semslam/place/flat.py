"""Which vocabulary the SLAM core uses for its descriptors, and the flat one it falls back to.

Only binary 32-byte descriptors (ORB) have a trained vocabulary here. ORB-SLAM-class
systems need a vocabulary for three things: restricting keyframe matching to features
under the same node (search by bag-of-words), relocalisation and loop detection. For
other descriptors (SIFT) we do what such systems do without a vocabulary:
``FlatVocabulary`` puts every feature under one node, so search by bag-of-words
degrades to brute-force matching with the descriptor kind's matcher (tracking against
the reference keyframe, triangulation still work); it cannot tell places apart, so
relocalisation is off (tracking stays lost) and loop closing is refused by the system.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from semslam.core.types import DescriptorKind, FeatureSpec
from semslam.errors import ConfigError
from semslam.place.vocabulary import (
    DESCRIPTOR_BYTES,
    BowVector,
    FeatureVector,
    Vocabulary,
    l1_score,
    load_default_vocabulary,
)


class FlatVocabulary:
    """A one-word "vocabulary": every image is the same bag of words, every feature falls
    under node 0 (so search by bag-of-words compares all pairs)."""

    recognises_places = False
    n_words = 1

    def __repr__(self) -> str:
        return "FlatVocabulary()"

    def bow(self, desc: NDArray[np.generic]) -> BowVector:
        if len(desc) == 0:
            return BowVector.empty()
        return BowVector(np.zeros(1, np.int32), np.ones(1))

    def transform(self, desc: NDArray[np.generic], levels_up: int | None = None
                  ) -> tuple[BowVector, FeatureVector]:
        """The one-word bag of words and all features under node 0 (``levels_up`` is ignored)."""
        if len(desc) == 0:
            return BowVector.empty(), {}
        return self.bow(desc), {0: np.arange(len(desc), dtype=np.int32)}

    @staticmethod
    def score(a: BowVector, b: BowVector) -> float:
        return l1_score(a, b)


def vocabulary_for(spec: FeatureSpec, setting: str) -> Vocabulary | FlatVocabulary:
    """The vocabulary for ``spec``'s descriptors: ``slam.vocabulary`` (``"default"`` = the
    shipped ORB one, else a path) for ORB's, ``FlatVocabulary`` for the others."""
    if spec.kind is DescriptorKind.BINARY and spec.dim == DESCRIPTOR_BYTES:
        return load_default_vocabulary() if setting == "default" else Vocabulary.load(setting)
    if setting != "default":
        raise ConfigError(f"slam.vocabulary: vocabularies are for {DESCRIPTOR_BYTES}-byte binary "
                          f"descriptors, not {spec.dim}-d {spec.kind.value} ones; "
                          "leave it at 'default' (a flat one is used)")
    return FlatVocabulary()
