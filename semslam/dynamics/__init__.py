"""Finding what moves: mask combination, keypoint rejection, multi-view geometry."""
