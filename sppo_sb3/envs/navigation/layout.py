"""Layouts: where the robot and every object start, drawn with keepouts, and where a reached goal goes next.

A restatement of Safety-Gymnasium's ``utils/random_generator.py`` that consumes its ``numpy.random.RandomState`` in the
same order, so that a seed gives Safety-Gymnasium's layout (``tests/envs/navigation`` checks it on recorded ones):

1. objects in placement order (the robot, then each group's objects); each draws up to 100 positions until one keeps
   ``keepout_a + margin + keepout_b`` from every object already placed; a layout that fails restarts, up to 10 000
   times;
2. a position is uniform in a placement rectangle shrunk by the object's keepout; with several rectangles, one is
   first chosen with probability proportional to its area; an object with a fixed location draws in a rectangle of
   half side ``keepout + 1e-9`` about it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: a placement rectangle ``(xmin, ymin, xmax, ymax)``
Rect = tuple[float, float, float, float]

#: attempts at a whole layout, and at one object's position within an attempt
LAYOUT_TRIES, OBJECT_TRIES = 10_000, 100
#: attempts at a new goal position
GOAL_TRIES = 10_000


class ResamplingError(RuntimeError):
    """No layout (or no new goal position) satisfies the keepouts; an episode whose goal cannot move ends."""


@dataclass(frozen=True)
class Placement:
    """Where one object may go: rectangles (``None``: the task's extents) and the radius it keeps free."""

    rects: tuple[Rect, ...] | None
    keepout: float


def fixed_location(xy: tuple[float, float], keepout: float) -> Placement:
    """The placement of an object with a fixed location: a rectangle of half side ``keepout + 1e-9`` about it."""
    k = keepout + 1e-9
    return Placement(((xy[0] - k, xy[1] - k, xy[0] + k, xy[1] + k),), keepout)


class LayoutSampler:
    """Draws layouts for one task.

    :param placements: every object's placement, by layout name, in drawing order (the robot, ``"agent"``, first).
    :param extents: the rectangle of placements without rectangles of their own.
    :param margin: extra distance kept between any two objects.
    """

    def __init__(self, placements: dict[str, Placement], extents: Rect, margin: float = 0.0) -> None:
        self.placements = placements
        self.extents = extents
        self.margin = margin

    def draw(self, rng: np.random.RandomState, placement: Placement) -> np.ndarray:
        """One position for ``placement``, uniform in its (area-weighted) rectangles shrunk by its keepout."""
        k = placement.keepout
        shrink = [(x0 + k, y0 + k, x1 - k, y1 - k) for x0, y0, x1, y1 in (placement.rects or (self.extents,))]
        if placement.rects is not None:
            shrink = [r for r in shrink if r[0] <= r[2] and r[1] <= r[3]]
            if not shrink:
                raise ValueError(f"no placement rectangle of {placement} holds its keepout {k}")
        if len(shrink) == 1:
            choice = shrink[0]
        else:
            areas = np.array([(x1 - x0) * (y1 - y0) for x0, y0, x1, y1 in shrink])
            choice = shrink[rng.choice(len(shrink), p=areas / np.sum(areas))]
        x0, y0, x1, y1 = choice
        return np.array([rng.uniform(x0, x1), rng.uniform(y0, y1)])

    def keeps_clear(self, xy: np.ndarray, keepout: float, layout: dict[str, np.ndarray]) -> bool:
        """Whether ``xy`` (with ``keepout``) keeps every object of ``layout`` at its distance."""
        for name, other in layout.items():
            if np.sqrt(np.sum(np.square(xy - other))) < self.placements[name].keepout + self.margin + keepout:
                return False
        return True

    def sample(self, rng: np.random.RandomState) -> dict[str, np.ndarray]:
        """A layout: every object's ``(x, y)``, by name, in placement order.

        :raises ResamplingError: after 10 000 failed attempts.
        """
        for _ in range(LAYOUT_TRIES):
            layout = self._attempt(rng)
            if layout is not None:
                return layout
        raise ResamplingError(f"no layout keeps every keepout after {LAYOUT_TRIES} attempts")

    def _attempt(self, rng: np.random.RandomState) -> dict[str, np.ndarray] | None:
        layout: dict[str, np.ndarray] = {}
        for name, placement in self.placements.items():
            for _ in range(OBJECT_TRIES):
                xy = self.draw(rng, placement)
                if self.keeps_clear(xy, placement.keepout, layout):
                    layout[name] = xy
                    break
            else:
                return None
        return layout

    def resample_goal(self, rng: np.random.RandomState, layout: dict[str, np.ndarray]) -> None:
        """Move ``layout["goal"]`` to a new position clear of every other object (in place).

        :raises ResamplingError: after 10 000 failed draws.
        """
        layout.pop("goal", None)
        placement = self.placements["goal"]
        for _ in range(GOAL_TRIES):
            xy = self.draw(rng, placement)
            if self.keeps_clear(xy, placement.keepout, layout):
                layout["goal"] = xy
                return
        raise ResamplingError(f"no goal position keeps every keepout after {GOAL_TRIES} draws")


def random_rotation(rng: np.random.RandomState) -> float:
    """A heading uniform in ``[0, 2π)``."""
    return float(rng.uniform(0, 2 * np.pi))
