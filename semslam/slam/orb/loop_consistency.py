"""Covisibility-consistency bookkeeping of loop detection (ORB-SLAM2 ``DetectLoop``).

A loop candidate is accepted only when candidates of several consecutive keyframes land in
the same place: each candidate brings its *group* (itself and its covisible keyframes),
and a group is consistent with a group of the previous keyframe if they share a keyframe.
ORB-SLAM2's rule, which keeps the number of groups from multiplying:

* each previous group is extended (count + 1) at most once, by the first candidate whose
  group touches it (``vbConsistentGroup``);
* a candidate touching no previous group starts a new group with count 0;
* a candidate is accepted once, when any previous group it touches reaches the threshold.

So after a keyframe there are at most ``len(previous groups) + len(candidates)`` groups,
and no more than ``len(candidates)`` when every candidate touches every previous group.

Plain ids and sets, no map: this runs without the map lock and is tested on its own.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

#: ORB-SLAM2's ``mnCovisibilityConsistencyTh``.
DEFAULT_THRESHOLD = 3


@dataclass(frozen=True)
class ConsistentGroup:
    """Keyframe ids of one candidate's covisibility group, and for how many consecutive
    keyframes before this one a connected group was a candidate."""

    members: frozenset[int]
    count: int


@dataclass(frozen=True)
class Candidate:
    """A loop candidate keyframe id and its group (the candidate and its covisibles)."""

    kf_id: int
    group: frozenset[int]

    @staticmethod
    def of(kf_id: int, covisible_ids: Iterable[int]) -> Candidate:
        return Candidate(kf_id, frozenset((kf_id, *covisible_ids)))


class LoopConsistency:
    """The consistent groups carried from one keyframe to the next."""

    def __init__(self, threshold: int = DEFAULT_THRESHOLD) -> None:
        self.threshold = threshold
        self.groups: list[ConsistentGroup] = []

    def reset(self) -> None:
        self.groups = []

    def update(self, candidates: Sequence[Candidate]) -> list[int]:
        """Advance by one keyframe with its candidates (in query order); return the ids of
        the candidates consistent for ``threshold`` keyframes, in that order."""
        previous = self.groups
        extended = [False] * len(previous)
        n_extended = 0
        groups: list[ConsistentGroup] = []
        accepted: list[int] = []
        for cand in candidates:
            consistent, enough = False, False
            for i, prev in enumerate(previous):
                if consistent and enough:  # only extending a group is left to do
                    if n_extended == len(previous):
                        break
                    if extended[i]:
                        continue
                if cand.group.isdisjoint(prev.members):
                    continue
                consistent = True
                count = prev.count + 1
                if not extended[i]:
                    groups.append(ConsistentGroup(cand.group, count))
                    extended[i] = True
                    n_extended += 1
                if count >= self.threshold and not enough:
                    accepted.append(cand.kf_id)
                    enough = True
            if not consistent:
                groups.append(ConsistentGroup(cand.group, 0))
        self.groups = groups
        return accepted
