"""The step problem of CPO (Achiam, Held, Tamar & Abbeel, ICML 2017, eq. 10) and its closed-form dual solution."""

from __future__ import annotations

import math
from dataclasses import dataclass

#: integer codes of :attr:`CPOSolution.case`, for the ``train/cpo_case`` log
CPO_CASES = {"infeasible": 0, "constrained": 1, "unconstrained": 2}


@dataclass(frozen=True)
class CPOSolution:
    """Solution of the CPO step problem, as the step ``x* = coef_g·H⁻¹g + coef_b·H⁻¹b``.

    :param case: ``"unconstrained"``: the linearised constraint does not cut the trust region, TRPO's step;
        ``"constrained"``: the dual solution ``x* = (H⁻¹g - ν*·H⁻¹b) / λ*`` (``ν*`` may still be 0);
        ``"infeasible"``: no point of the trust region satisfies the constraint, recovery step ``-sqrt(2δ/s)·H⁻¹b``
        (zero when ``b = 0``: nothing decreases the cost to first order).
    :param lam: the dual variable ``λ*`` of the trust region (``nan`` in the infeasible case).
    :param nu: the dual variable ``ν*`` of the cost constraint (``nan`` in the infeasible case).
    :param coef_g: coefficient of ``H⁻¹g`` in the step.
    :param coef_b: coefficient of ``H⁻¹b`` in the step.
    """

    case: str
    lam: float
    nu: float
    coef_g: float
    coef_b: float


def cpo_dual_solution(q: float, r: float, s: float, c: float, delta: float, eps: float = 1e-8) -> CPOSolution:
    """Closed-form solution of CPO's step problem through its dual (Achiam et al. 2017, eq. 10 and Appendix 10.2).

    Problem: ``max_x gᵀx  s.t.  c + bᵀx <= 0,  ½ xᵀHx <= δ``, with ``q = gᵀH⁻¹g``, ``r = gᵀH⁻¹b``, ``s = bᵀH⁻¹b``.
    The dual function (minimised over ``λ >= 0, ν >= 0``; Achiam's dual is its negative) is
    ``D(λ, ν) = (q - 2νr + ν²s) / (2λ) - νc + λδ`` and the primal solution is ``x* = (H⁻¹g - ν*·H⁻¹b) / λ*``.
    For fixed ``λ`` the best ``ν`` is ``ν(λ) = max(0, (λc + r) / s)``, which splits ``λ >= 0`` in two:

    - ``Λ_a = {λc + r > 0}`` (``ν > 0``): ``D_a(λ) = A / (2λ) + λB/2 - rc/s``, ``A = q - r²/s``, ``B = 2δ - c²/s``,
      minimised at ``λ = sqrt(A / B)``;
    - ``Λ_b = {λc + r <= 0}`` (``ν = 0``): ``D_b(λ) = q / (2λ) + λδ``, minimised at ``λ = sqrt(q / (2δ))``.

    Each unconstrained minimiser is projected onto its interval and the better of the two is ``λ*``. Before that,
    the two degenerate cases of Achiam's Section 6.2: if ``c > 0`` and ``B < 0`` the trust region holds no
    feasible point (``c - sqrt(2δs) > 0``): recovery step ``x* = -sqrt(2δ/s)·H⁻¹b``; if ``c < 0`` and ``B < 0`` the
    constraint cannot bind inside the trust region: TRPO's step ``x* = sqrt(2δ/q)·H⁻¹g``.

    :param q: ``gᵀH⁻¹g >= 0``.
    :param r: ``gᵀH⁻¹b``.
    :param s: ``bᵀH⁻¹b >= 0``.
    :param c: constraint value ``J_C(π_k) - d`` (in the units of the cost surrogate).
    :param delta: trust-region size ``δ > 0`` (the KL bound; the trust region is ``½ xᵀHx <= δ``).
    :param eps: threshold below which ``q``, ``s``, ``λ`` count as 0.
    :return: the dual variables and the step's coefficients.
    """
    q, r, s, c, delta = float(q), float(r), float(s), float(c), float(delta)
    if delta <= 0:
        raise ValueError(f"The trust-region size delta must be > 0, got {delta}.")
    q, s = max(q, 0.0), max(s, 0.0)
    degenerate = _degenerate_solution(q, r, s, c, delta, eps)
    if degenerate is not None:
        return degenerate
    lam = _best_lambda(q, r, s, c, delta, eps)
    if not math.isfinite(lam):  # B = 0 and Λ_a unbounded: the trust region touches the constraint at one point
        return CPOSolution("constrained", math.inf, math.inf, 0.0, -c / s)
    nu = max(0.0, (lam * c + r) / s)
    return CPOSolution("constrained", lam, nu, 1.0 / lam, -nu / lam)


def _trpo_step(q: float, delta: float, eps: float) -> CPOSolution:
    """TRPO's step ``x* = sqrt(2δ/q)·H⁻¹g``, where the cost constraint does not bind (zero when ``g = 0``)."""
    if q <= eps:
        return CPOSolution("unconstrained", math.inf, 0.0, 0.0, 0.0)
    lam = math.sqrt(q / (2.0 * delta))
    return CPOSolution("unconstrained", lam, 0.0, 1.0 / lam, 0.0)


def _degenerate_solution(q: float, r: float, s: float, c: float, delta: float, eps: float) -> CPOSolution | None:
    """The cases that need no dual search (Achiam et al. 2017, Section 6.2), or ``None``.

    No cost gradient (``s = 0``); no feasible point in the trust region (recovery); a constraint that cannot bind
    (TRPO's step); and ``g ∥ b`` in the ``H``-metric (``A = 0``), solved on the line ``H⁻¹b`` directly, since the
    general formula would divide by ``λ* = sqrt(A/B) = 0`` and cancel two huge terms.
    """
    if s <= eps:  # no first-order cost information: the linearised constraint is just c <= 0
        return _trpo_step(q, delta, eps) if c <= 0 else CPOSolution("infeasible", math.nan, math.nan, 0.0, 0.0)
    big_b = 2.0 * delta - c * c / s
    if c > 0 and big_b < 0:
        return CPOSolution("infeasible", math.nan, math.nan, 0.0, -math.sqrt(2.0 * delta / s))
    if c < 0 and big_b < 0:
        return _trpo_step(q, delta, eps)
    if max(q - r * r / s, 0.0) <= 1e-10 * q:
        if r > 0 and -c / s < math.sqrt(2.0 * delta / s):  # the constraint, not the trust region, stops the step
            return CPOSolution("constrained", 0.0, r / s, 0.0, -c / s)
        return _trpo_step(q, delta, eps)
    return None


def _lambda_intervals(r: float, c: float) -> tuple[tuple[float, float] | None, tuple[float, float] | None]:
    """``Λ_a = {λ >= 0: λc + r > 0}`` and ``Λ_b = {λ >= 0: λc + r <= 0}``, as ``(low, high)`` or ``None`` when empty."""
    if c == 0:
        return ((0.0, math.inf), None) if r > 0 else (None, (0.0, math.inf))
    split = -r / c
    if c > 0:
        return (max(0.0, split), math.inf), ((0.0, split) if split >= 0 else None)
    return ((0.0, split) if split > 0 else None), (max(0.0, split), math.inf)


def _best_lambda(q: float, r: float, s: float, c: float, delta: float, eps: float) -> float:
    """``λ*``: each interval's unconstrained minimiser of the dual, projected onto it, the better of the two."""
    big_a, big_b = max(q - r * r / s, 0.0), 2.0 * delta - c * c / s
    lam_a_set, lam_b_set = _lambda_intervals(r, c)
    candidates: list[tuple[float, float]] = []  # (dual value, λ)
    if lam_a_set is not None:
        lam_a = math.sqrt(big_a / big_b) if big_b > eps else math.inf
        lam_a = min(max(lam_a, lam_a_set[0], eps), lam_a_set[1])
        candidates.append((big_a / (2.0 * lam_a) + lam_a * big_b / 2.0 - r * c / s, lam_a))  # D_a(λ)
    if lam_b_set is not None:
        lam_b = min(max(math.sqrt(q / (2.0 * delta)), lam_b_set[0], eps), lam_b_set[1])
        candidates.append((q / (2.0 * lam_b) + lam_b * delta, lam_b))  # D_b(λ)
    return min(candidates)[1]
