"""Place recognition over the ego keyframes (issue #18): which earlier keyframes look
like this one, whatever the odometry believes about where they are. Used to
relocalise a segment that starts after a tracking break, and to propose loop
closures that the pose-based search cannot see (drifted odometry on a whole floor).

A bag of visual words on the keyframes' SIFT descriptors, tf-idf weighted and scored
by cosine similarity [Sivic & Zisserman 2003; DBoW2's scoring without its tree]. The
vocabulary is k-means (scipy) over the descriptors of the recording's first keyframes:
no vocabulary file to ship, and a building's own words tell its places apart. A
retrieved keyframe is only a candidate: the multiway registration verifies it (SIFT
matches + PnP RANSAC, then dense refinement), as it does every loop."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.cluster.vq import kmeans2, vq


@dataclass(frozen=True)
class RetrievalParams:
    enabled: bool = True  # place recognition: relocalisation after tracking breaks, loops by appearance
    words: int = 256  # vocabulary size [count]
    vocabulary_keyframes: int = 8  # the vocabulary is built once this many keyframes have descriptors [count]
    vocabulary_iterations: int = 10  # k-means iterations (seeded: runs are repeatable) [count]
    # Best-scoring earlier keyframes verified per keyframe of a segment not yet joined to the
    # walk (relocalisation) [count].
    relocalisation_candidates: int = 3
    # Best-scoring earlier keyframes verified per keyframe of a joined segment (loop closures by appearance) [count].
    loop_candidates: int = 1
    min_score: float = 0.1  # cosine similarity of the tf-idf vectors a retrieved keyframe needs [cos]


class PlaceIndex:
    """Word histograms of the keyframes added in order; `query` ranks earlier ones."""

    def __init__(self, params: RetrievalParams = RetrievalParams()):
        self.params = params
        self.codebook: np.ndarray | None = None
        self._pending: list[np.ndarray] = []  # descriptors until the vocabulary exists
        # Histograms in a buffer that doubles as it fills (one query per keyframe must not
        # copy every earlier histogram), and how many keyframes hold each word.
        self._counts = np.zeros((0, params.words))
        self._n = 0
        self._df = np.zeros(params.words)

    def __len__(self) -> int:
        return self._n + len(self._pending)

    def add(self, descriptors: np.ndarray) -> None:
        """The next keyframe's (N, 128) descriptors."""
        if self.codebook is not None:
            self._append(self._histogram(descriptors))
            return
        self._pending.append(np.asarray(descriptors, np.float32))
        if len(self._pending) >= self.params.vocabulary_keyframes:
            self._build()

    def query(self, keyframe: int, allowed) -> list[tuple[int, float]]:
        """(keyframe index, score) of the `allowed` keyframes most similar to `keyframe`,
        best first, above `min_score`; empty while too few descriptors exist for a
        vocabulary."""
        if self.codebook is None:
            self._build()
            if self.codebook is None:
                return []
        allowed = np.asarray(list(allowed), dtype=int)
        if not len(allowed):
            return []
        idf = np.log(self._n / np.maximum(self._df, 1))
        W = self._counts[np.r_[keyframe, allowed]] * idf
        W /= np.maximum(np.linalg.norm(W, axis=1, keepdims=True), 1e-12)
        scores = W[1:] @ W[0]
        order = np.argsort(-scores, kind="stable")
        return [(int(allowed[i]), float(scores[i])) for i in order if scores[i] >= self.params.min_score]

    def _build(self) -> None:
        data = np.vstack(self._pending) if self._pending else np.zeros((0, 128), np.float32)
        if len(data) < 4 * self.params.words:
            return
        self.codebook, _ = kmeans2(data, self.params.words, iter=self.params.vocabulary_iterations, minit="++", seed=0)
        for d in self._pending:
            self._append(self._histogram(d))
        self._pending = []

    def _append(self, histogram: np.ndarray) -> None:
        if self._n == len(self._counts):
            self._counts = np.vstack([self._counts, np.zeros((max(self._n, 16), self.params.words))])
        self._counts[self._n] = histogram
        self._n += 1
        self._df += histogram > 0

    def _histogram(self, descriptors: np.ndarray) -> np.ndarray:
        if not len(descriptors):
            return np.zeros(self.params.words)
        words, _ = vq(np.asarray(descriptors, np.float32), self.codebook, check_finite=False)
        return np.bincount(words, minlength=self.params.words).astype(float)
