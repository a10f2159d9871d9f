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
    positions: np.ndarray, agent_pos: np.ndarray, agent_mat: np.ndarray, max_dist: float, num_bins: int = NUM_BINS
) -> np.ndarray:
    """The pseudo-lidar reading of a set of objects.

    :param positions: the objects' positions, ``(n, 2)`` or ``(n, 3)`` (the height is ignored).
    :param agent_pos: the robot body's position, ``(3,)``.
    :param agent_mat: the robot body's orientation, a 3×3 rotation matrix.
    :param max_dist: the distance at and beyond which an object reads 0.
    :param num_bins: the number of bins.
    :return: ``(num_bins,)`` readings in ``[0, 1]``.
    """
    reading = np.zeros(num_bins)
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, np.shape(positions)[-1])
    if not len(positions):
        return reading
    world = np.c_[positions[:, :2], np.zeros(len(positions))] - agent_pos
    ego = (world @ agent_mat)[:, :2]
    dist = np.hypot(ego[:, 0], ego[:, 1])
    angle = np.arctan2(ego[:, 1], ego[:, 0]) % (2 * np.pi)
    bin_size = 2 * np.pi / num_bins
    index = np.minimum((angle / bin_size).astype(np.int64), num_bins - 1)  # an angle rounded up to 2π
    sensor = np.maximum(0.0, max_dist - dist) / max_dist
    alias = (angle - bin_size * index) / bin_size
    np.maximum.at(reading, index, sensor)
    np.maximum.at(reading, (index + 1) % num_bins, alias * sensor)
    np.maximum.at(reading, (index - 1) % num_bins, (1 - alias) * sensor)
    return reading
