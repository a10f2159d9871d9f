"""Safety-Gymnasium's pseudo-lidar: per kind of object, 16 bins around the robot that read how close the nearest is.

An object at egocentric angle ``θ`` and distance ``d`` falls in bin ``⌊θ / (2π/16)⌋`` and reads
``max(0, d_max − d) / d_max``; with aliasing, the neighbouring bins read that value times how far ``θ`` lies towards
them (``alias`` for the next bin, ``1 − alias`` for the previous one). Each bin keeps the largest reading. The
egocentric vector is the world vector from the robot body to the object's ``(x, y, 0)``, rotated into the body's frame.
"""

from __future__ import annotations

import numpy as np

#: bins per kind of object
NUM_BINS = 16


def pseudo_lidar(
    positions: np.ndarray,
    agent_pos: np.ndarray,
    agent_mat: np.ndarray,
    max_dist: float,
    num_bins: int = NUM_BINS,
    kinds: np.ndarray | None = None,
    num_kinds: int = 1,
) -> np.ndarray:
    """The pseudo-lidar reading of a set of objects, or of several kinds of object at once.

    :param positions: the objects' positions, ``(n, 2)`` or ``(n, 3)`` (the height is ignored).
    :param agent_pos: the robot body's position, ``(3,)``.
    :param agent_mat: the robot body's orientation, a 3×3 rotation matrix.
    :param max_dist: the distance at and beyond which an object reads 0.
    :param num_bins: the number of bins.
    :param kinds: ``(n,)`` each object's kind, in ``[0, num_kinds)`` (``None``: all of one kind).
    :param num_kinds: the number of kinds.
    :return: ``(num_bins,)`` readings in ``[0, 1]``, or ``(num_kinds, num_bins)`` when ``kinds`` is given.
    """
    reading = np.zeros(num_kinds * num_bins)
    positions = np.asarray(positions, dtype=np.float64)
    if positions.size:
        world = -agent_pos[None].repeat(len(positions), axis=0)
        world[:, :2] += positions[:, :2]
        ego = world @ agent_mat
        dist = np.hypot(ego[:, 0], ego[:, 1])
        angle = np.arctan2(ego[:, 1], ego[:, 0]) % (2 * np.pi)
        bin_size = 2 * np.pi / num_bins
        index = np.minimum((angle / bin_size).astype(np.int64), num_bins - 1)  # an angle rounded up to 2π
        sensor = np.maximum(0.0, max_dist - dist) / max_dist
        alias = (angle - bin_size * index) / bin_size
        offset = np.zeros(len(index), dtype=np.int64) if kinds is None else np.asarray(kinds) * num_bins
        bins = np.concatenate([index, (index + 1) % num_bins, (index - 1) % num_bins]) + np.tile(offset, 3)
        np.maximum.at(reading, bins, np.concatenate([sensor, alias * sensor, (1 - alias) * sensor]))
    return reading if kinds is None else reading.reshape(num_kinds, num_bins)
