"""The navigation tasks' shield: it reads the simulator state, keeps proposals out of static constraints, fails closed."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.vec_env import DummyVecEnv
from tiny_hyperparams import TINY_SAILR, TINY_SPPO

import sppo_sb3
from sppo_sb3.common.action_repeat import ActionRepeat
from sppo_sb3.common.keys import EDITS_KEY, INTERVENTIONS_KEY
from sppo_sb3.envs.navigation import SafetyNavigationEnv
from sppo_sb3.envs.navigation.objects import Gremlins
from sppo_sb3.envs.navigation.tasks.button import ButtonTask
from sppo_sb3.shield import ConstraintSteps, ShieldFailure, ShieldWrapper
from sppo_sb3.shield.registry import default_shielding_rule
from sppo_sb3.shield.tasks.navigation import (
    GREMLIN_MARGIN,
    NavigationConstraint,
    NavigationShieldingRule,
    mocap_columns,
    navigation_task,
    physics_size,
    shield_model,
)
from sppo_sb3.shield.tasks.navigation import shield_state as to_shield_state


def toward_nearest(env: SafetyNavigationEnv, prefix: str, exclude: str | None = None) -> np.ndarray:
    """The action that drives the robot straight at the nearest object named ``prefix…`` but ``exclude`` (an
    adversarial proposal)."""
    return toward_nearest_body(env, [name for name in env.layout if name.startswith(prefix) and name != exclude])


def toward_nearest_body(env: SafetyNavigationEnv, names: list[str]) -> np.ndarray:
    """The action that drives the robot straight at the nearest of the bodies ``names``."""
    agent = env.world.agent_xpos()[:2]
    targets = env.world.body_xpos(names)[:, :2]
    return toward_point(env, targets[np.argmin(np.linalg.norm(targets - agent, axis=1))])


def toward_point(env: SafetyNavigationEnv, target: np.ndarray) -> np.ndarray:
    """The action that drives the robot straight at the point ``target`` ``(x, y)``."""
    agent = env.world.agent_xpos()[:2]
    ego_x, ego_y = (np.r_[target - agent, 0.0] @ env.world.agent_xmat())[:2]
    if env.world.robot.name == "Point":  # drives along its x axis; the second control turns it counterclockwise
        return np.array([1.0, float(np.clip(3 * np.arctan2(ego_y, ego_x), -1, 1))])
    turn = float(np.clip(3 * np.arctan2(ego_x, -ego_y), -1, 1))  # the Car drives along -y; [1, -1] turns it left
    return np.clip(np.array([1.0 + turn, 1.0 - turn]), -1, 1)


def test_auto_finds_a_rule_for_every_constrained_task_and_none_for_level_zero() -> None:
    assert isinstance(default_shielding_rule("sppo_sb3/SafetyPointGoal1-v0"), NavigationShieldingRule)
    assert default_shielding_rule("sppo_sb3/SafetyCarCircle2-v0") is not None
    assert default_shielding_rule("sppo_sb3/SafetyPointGoal0-v0") is None


def test_the_shield_state_predicts_the_env_step() -> None:
    """The shield model, from the state it reads, steps as the env does (the Point's frame change included)."""
    env = SafetyNavigationEnv("Point", "Goal", 1)
    rule = NavigationShieldingRule("Point", "Goal", 1)
    env.reset(seed=3)
    action = np.array([[0.7, -0.4]])
    for _ in range(5):
        state = to_shield_state(env, rule.model)
        predicted = rule.next_states(state[None], action)[0]
        env.step(action[0])
        actual = to_shield_state(env, rule.model)
        np.testing.assert_allclose(predicted[1:4], actual[1:4], atol=1e-6)  # x, y, heading
        np.testing.assert_allclose(predicted[4:7], actual[4:7], atol=1e-4)  # velocities


@pytest.mark.parametrize(
    ("env_id", "prefix"),
    [
        ("sppo_sb3/SafetyPointGoal1-v0", "hazard"),
        ("sppo_sb3/SafetyCarGoal1-v0", "hazard"),
        ("sppo_sb3/SafetyPointGoal2-v0", "vase"),
        ("sppo_sb3/SafetyCarGoal2-v0", "vase"),
        ("sppo_sb3/SafetyPointPush2-v0", "pillar"),
    ],
)
def test_adversarial_proposals_never_reach_a_static_constraint(env_id: str, prefix: str) -> None:
    env = gym.make(env_id)
    shielded = ShieldWrapper(env, default_shielding_rule(env_id, env))
    inner = env.unwrapped
    assert isinstance(inner, SafetyNavigationEnv)
    shielded.reset(seed=1)
    costs = interventions = 0
    for _ in range(200):
        _, _, terminated, truncated, info = shielded.step(toward_nearest(inner, prefix))
        costs += info["cost"]
        interventions += info["shield_intervened"]
        if terminated or truncated:
            shielded.reset()
    assert costs == 0
    assert interventions > 0  # the proposals did head into the constraint


def run_proposals(
    env: SafetyNavigationEnv,
    propose: Callable[[SafetyNavigationEnv], np.ndarray],
    rule: NavigationShieldingRule | None,
    steps: int,
    cost_key: str = "cost",
) -> tuple[list[bool], int]:
    """``steps`` steps of ``env`` from where it is under ``propose``'s proposals, through ``rule`` if given: whether
    each step paid ``cost_key``, and the rule's interventions."""
    obs = env.last_obs
    assert obs is not None
    costly, interventions = [], 0
    for _ in range(steps):
        proposal = propose(env)
        if rule is not None:
            decision = rule.shield(obs[None], proposal[None])
            proposal, interventions = decision.actions[0], interventions + int(decision.intervened[0])
        obs, _, _, _, info = env.step(proposal)
        costly.append(info.get(cost_key, 0.0) > 0)
    return costly, interventions


def drive_on_button1(
    seed: int, adversary: Callable[[SafetyNavigationEnv], np.ndarray], cost_key: str, shielded: bool
) -> tuple[int, int]:
    """300 steps of PointButton1 under ``adversary``'s proposals, through the rule or not: the steps that paid
    ``cost_key`` and the rule's interventions."""
    env = SafetyNavigationEnv("Point", "Button", 1)
    env.reset(seed=seed)
    rule = NavigationShieldingRule("Point", "Button", 1) if shielded else None
    costly, interventions = run_proposals(env, adversary, rule, 300, cost_key)
    return sum(costly), interventions


def toward_a_wrong_button(env: SafetyNavigationEnv) -> np.ndarray:
    """Drive at the nearest button that is not the goal."""
    task = env.task
    assert isinstance(task, ButtonTask)
    return toward_nearest(env, "button", exclude=f"button{task.goal_button}")


@pytest.mark.parametrize("shielded", [True, False])
def test_adversarial_proposals_never_press_a_wrong_button(shielded: bool) -> None:
    """Button 1: driving at the nearest button that is not the goal; unshielded, the same proposals press one."""
    presses, interventions = drive_on_button1(1, toward_a_wrong_button, "cost_buttons", shielded)
    if shielded:
        assert presses == 0 and interventions > 0
    else:
        assert presses > 0  # so the shielded case can fail


def test_the_robot_leaves_the_button_it_pressed() -> None:
    """PointButton1, seed 2: the robot drives at the goal button and presses it, and the goal moves to another button;
    the pressed one becomes a wrong one once the env's 10-step delay is over, with the robot on it, inside the unsafe
    set. Creeping on at it, the rule leads the robot off it; alone (or with eq. 12 on the absorbing tail alone, which
    passes every proposal there) the robot presses it 30 times in 40 steps."""
    env = SafetyNavigationEnv("Point", "Button", 1)
    rule = NavigationShieldingRule("Point", "Button", 1)
    env.reset(seed=2)
    task = env.task
    assert isinstance(task, ButtonTask)
    goal = task.goal_button
    while task.goal_button == goal:
        env.step(toward_nearest_body(env, [f"button{goal}"]))
    pressed = env.get_state()

    def creep(env: SafetyNavigationEnv) -> np.ndarray:
        return 0.3 * toward_nearest_body(env, [f"button{goal}"])

    alone, _ = run_proposals(env, creep, None, 40, "cost_buttons")
    env.set_state(pressed)
    shielded, interventions = run_proposals(env, creep, rule, 40, "cost_buttons")
    assert any(alone)  # so the shielded case can fail
    assert not any(shielded) and interventions > 0


def test_the_rule_predicts_where_the_gremlins_go() -> None:
    """The rolled gremlin markers follow the env's welded gremlins within the margin added to their reach."""
    env = SafetyNavigationEnv("Point", "Button", 1)
    rule = NavigationShieldingRule("Point", "Button", 1)
    env.reset(seed=0)
    for _ in range(20):  # the welds settle after reset
        env.step(np.zeros(2))
    gremlins = [f"gremlin{i}obj" for i in range(4)]
    start = to_shield_state(env, rule.model)
    columns = [mocap_columns(rule.model, body) for body in gremlins]
    steps = rule.rollout_steps(start[None], np.zeros((1, rule.horizon, 2)))  # the rule's lookahead
    worst, held_still = 0.0, 0.0
    for k in range(rule.horizon):
        env.step(np.zeros(2))
        actual = env.world.body_xpos(gremlins)[:, :2]
        predicted = np.array([steps.after[0, k, list(c)] for c in columns])
        worst = max(worst, float(np.max(np.linalg.norm(predicted - actual, axis=1))))
        held_still = max(held_still, float(np.max(np.linalg.norm(start[np.array(columns)] - actual, axis=1))))
    assert worst < GREMLIN_MARGIN < held_still


def gremlin_on_its_circle(time: float = 2.0) -> tuple[NavigationConstraint, np.ndarray, Callable[..., np.ndarray]]:
    """PointButton1's constraint, a shield state at ``time`` with every gremlin box on one circle, and where the robot
    is at ``angle`` radians ahead of the box along it, ``out`` metres out of it."""
    definition = navigation_task("Point", "Button", 1)
    model = shield_model(definition)
    constraint = NavigationConstraint.of(definition, model)
    centre, travel = np.array([0.5, -0.3]), constraint.gremlin_travel
    state = np.zeros(physics_size(model) + 3 * model.nmocap)
    state[0] = time

    def on_circle(angle: float, out: float = 0.0) -> np.ndarray:
        return centre + (travel + out) * np.array([np.sin(time + angle), np.cos(time + angle)])

    for x, y in constraint.gremlin_columns:
        state[[x, y]] = on_circle(0.0)
    return constraint, state, on_circle


def test_the_robot_keeps_off_the_path_ahead_of_a_gremlin_not_the_one_behind_it() -> None:
    """A plan that ends where a gremlin will be within the sweep is unsafe, though the gremlin is as far as behind."""
    constraint, state, on_circle = gremlin_on_its_circle()

    def margin(angle: float, sweep: float = constraint.gremlin_sweep) -> float:
        """The first gremlin's margin with the robot on its circle ``angle`` radians ahead of it."""
        swept = replace(constraint, gremlin_sweep=sweep)
        return float(swept.gremlin_margins(swept.gremlin_frame(state, on_circle(angle)))[0])

    assert margin(1.8) < 0 < margin(-1.8)  # the same distance from the box, ahead of it and behind it
    assert margin(4.0) > 0  # beyond the sweep's end
    assert margin(1.8, sweep=0.0) > 0 and margin(1.8, sweep=0.0) == pytest.approx(margin(-1.8, sweep=0.0))  # the box alone
    assert margin(0.0) == pytest.approx(-constraint.gremlin_reach)  # on the box


def test_inside_a_gremlins_path_the_way_out_is_ahead_of_it_or_outwards() -> None:
    """The gremlin arrives where the robot is after the arc to the edge of its reach; the depth the rule leads out of
    shrinks ahead along the path and outwards from it, so a robot inside leaves before the gremlin comes."""
    constraint, state, on_circle = gremlin_on_its_circle()
    reach, travel = constraint.gremlin_reach, constraint.gremlin_travel
    robot = np.zeros_like(state)

    def arrival(angle: float, out: float = 0.0) -> float:
        return float(constraint.gremlin_arrivals(constraint.gremlin_frame(state, on_circle(angle, out)))[0])

    def depth(angle: float, out: float = 0.0) -> float:
        robot[:] = state
        robot[1:3] = on_circle(angle, out)  # qpos[0:2]: the robot body's (x, y)
        return float(constraint.keep_out(robot)[1])

    half_width = 2 * np.arcsin(reach / (2 * travel))  # the box reaches a point of its circle this far either side
    assert arrival(half_width + 0.4) == pytest.approx(0.4)
    assert arrival(0.1) == 0.0 and arrival(-0.1) == 0.0  # within reach now, ahead or behind
    assert arrival(1.0, out=reach + 0.01) == np.inf  # out of reach of the whole circle
    depths = [depth(angle) for angle in (0.9, 1.2, 1.5)]
    assert depths[0] > depths[1] > depths[2] > 0
    assert depth(1.2) > depth(1.2, out=0.5 * reach) > 0 == depth(1.2, out=1.01 * reach)


def into_the_gap(env: SafetyNavigationEnv) -> Callable[[SafetyNavigationEnv], np.ndarray]:
    """Proposals that drive the robot into the gap between the wrong button nearest a gremlin's circle and that circle,
    then push it at the button: the gremlin, coming round, corners it there."""
    task = env.task
    assert isinstance(task, ButtonTask)
    travel = next(group.travel for group in task.groups if isinstance(group, Gremlins))
    buttons = [env.layout[f"button{i}"] for i in range(4) if i != task.goal_button]
    centres = [env.layout[f"gremlin{i}"] for i in range(4)]
    button, centre = min(((b, c) for b in buttons for c in centres), key=lambda pair: np.linalg.norm(pair[0] - pair[1]))
    outward = (button - centre) / np.linalg.norm(button - centre)
    gap = centre + outward * (travel + (np.linalg.norm(button - centre) - travel) / 2)

    def propose(env: SafetyNavigationEnv) -> np.ndarray:
        in_gap = np.linalg.norm(env.world.agent_xpos()[:2] - gap) < 0.15
        return toward_point(env, button if in_gap else gap)

    return propose


def test_touching_a_gremlin_is_priced_above_standing_in_its_path() -> None:
    """Both are unsafe; the touch also costs in the env, so it pays a second absorbing tail from its first step."""
    rule = NavigationShieldingRule("Point", "Button", 1)
    _, state, on_circle = gremlin_on_its_circle()

    def cost_standing(angle: float) -> float:
        after = np.repeat(state[None, None], rule.horizon, axis=1)
        after[..., 1:3] = on_circle(angle)  # the robot body's (x, y)
        empty = np.zeros((1, rule.horizon, 0))
        return float(rule.discounted_cost(ConstraintSteps(rule.model, after, after, empty, empty, 0.02))[0])

    in_path, touching = cost_standing(1.5), cost_standing(0.0)  # 1.5 rad ahead of the box: in its path, out of its reach
    assert in_path > rule.gamma / (1 - rule.gamma)  # unsafe from the first step
    assert touching - in_path > rule.gamma / (1 - rule.gamma)


@pytest.mark.parametrize(
    ("seed", "before"), [(1, "40 steps in a hazard"), (10, "4 presses"), (26, "31 steps touching a gremlin")]
)
def test_a_robot_pushed_between_a_gremlins_circle_and_what_costs_gets_out_of_the_way(seed: int, before: str) -> None:
    """PointButton1: proposals hold the robot between a wrong button and a gremlin's circle and push it at the button
    (seed 1: past a hazard); the gremlin comes round. Touching the gremlin, the button or the hazard costs, standing in
    the gremlin's path ahead does not yet, and the rule prices them so; inside the path it leads ahead of the gremlin
    or outwards (:meth:`~sppo_sb3.shield.tasks.navigation.NavigationConstraint.keep_out_depth`), looking far enough
    ahead to find the way round what blocks the shortest way out. It pays nothing; the rule before these paid
    ``before`` (checked on 668f07f)."""
    env = SafetyNavigationEnv("Point", "Button", 1)
    env.reset(seed=seed)
    propose, start = into_the_gap(env), env.get_state()
    alone, _ = run_proposals(env, propose, None, 300, "cost_buttons")
    env.set_state(start)
    costly, interventions = run_proposals(env, propose, NavigationShieldingRule("Point", "Button", 1), 300, "cost")
    assert any(alone)  # so the shielded case can fail
    assert not any(costly) and interventions > 0


@pytest.mark.parametrize("shielded", [True, False])
def test_adversarial_proposals_never_touch_a_circling_gremlin(shielded: bool) -> None:
    """Button 1: driving at the nearest gremlin, which keeps moving; unshielded, the same proposals touch one."""
    gremlins = [f"gremlin{i}obj" for i in range(4)]
    # seed 3: a layout where gremlins held still in the rule's rollouts are touched 52 times
    touches, interventions = drive_on_button1(3, lambda env: toward_nearest_body(env, gremlins), "cost_gremlins", shielded)
    if shielded:
        assert touches == 0 and interventions > 0
    else:
        assert touches > 0  # so the shielded case can fail


def test_ranked_adversarial_candidates_never_reach_a_hazard() -> None:
    """``shield_first_accepted`` on a rule with memory (warm plans): every candidate heads into or near the nearest
    hazard; whichever is executed, the robot never enters one, and alternatives do get executed."""
    env = SafetyNavigationEnv("Point", "Goal", 1)
    rule = NavigationShieldingRule("Point", "Goal", 1)
    obs, _ = env.reset(seed=1)
    rng = np.random.default_rng(0)
    costs, chosen = 0.0, []
    for _ in range(200):
        adversary = toward_nearest(env, "hazard")
        candidates = np.clip(adversary + rng.normal(0.0, 0.5, (4, 2)), -1, 1)
        candidates[0] = adversary
        decision, choice = rule.shield_first_accepted(obs[None], candidates[None])
        obs, _, terminated, truncated, info = env.step(decision.actions[0])
        costs += info["cost"]
        chosen.append(int(choice[0]))
        if terminated or truncated:
            obs, _ = env.reset()
    assert costs == 0
    assert -1 in chosen and any(k > 0 for k in chosen)  # the backup and an alternative both ran


def steps_beyond_the_wall(shielded: bool, steps: int = 60) -> tuple[list[bool], int]:
    """PointCircle1, seed 0: drive out through the wall at ``x = 1.125`` unshielded, then keep driving outwards for
    ``steps`` steps; whether each of those cost, and the interventions."""
    env = SafetyNavigationEnv("Point", "Circle", 1)
    env.reset(seed=0)

    def outwards(env: SafetyNavigationEnv) -> np.ndarray:
        return toward_point(env, np.array([3.0, 0.0]))

    while not any(run_proposals(env, outwards, None, 1)[0]):
        pass
    rule = NavigationShieldingRule("Point", "Circle", 1) if shielded else None
    return run_proposals(env, outwards, rule, steps)


def test_beyond_a_wall_the_shield_leads_the_robot_back() -> None:
    """Inside the unsafe set every plan pays the violation; the steps each spends inside, and how deep, rank them, so
    the shield replaces the proposals that go on out (eq. 12 on the absorbing tail alone would pass them: ``Ā = 0``)."""
    unshielded, _ = steps_beyond_the_wall(shielded=False)
    shielded, interventions = steps_beyond_the_wall(shielded=True)
    assert all(unshielded)  # the proposals alone stay out
    assert interventions > 0 and sum(shielded) < 45 and not any(shielded[-10:])  # back inside, and it stays


def test_random_proposals_stay_safe_on_circle_walls() -> None:
    env = gym.make("sppo_sb3/SafetyPointCircle2-v0")
    shielded = ShieldWrapper(env, default_shielding_rule("sppo_sb3/SafetyPointCircle2-v0", env))
    shielded.reset(seed=0)
    rng = np.random.default_rng(0)
    costs = sum(shielded.step(rng.uniform(-1, 1, 2))[4]["cost"] for _ in range(300))
    assert costs == 0


@pytest.mark.parametrize("shielded, permissive", [(True, False), (True, True), (False, False)])
def test_a_proposal_held_into_a_hazard_costs_nothing_behind_the_shield(shielded: bool, permissive: bool) -> None:
    """Held for 5 env steps (0.1 s, the field's time scale), a proposal straight at the nearest hazard never reaches
    it: the shield checks every held env step, also where it edits the proposal instead of executing the backup's
    action. Unshielded, the same held proposals pay (so the test can fail)."""
    env = gym.make("sppo_sb3/SafetyPointGoal1-v0")
    inner = env.unwrapped
    assert isinstance(inner, SafetyNavigationEnv)
    held = ShieldWrapper(env, "auto", action_repeat=5, permissive=permissive) if shielded else ActionRepeat(env, 5)
    held.reset(seed=1)
    costs = interventions = edits = 0
    for _ in range(60):
        _, _, terminated, truncated, info = held.step(toward_nearest(inner, "hazard"))
        costs += info["cost"]
        interventions += info.get(INTERVENTIONS_KEY, 0)
        edits += info.get(EDITS_KEY, 0)
        assert not (terminated or truncated)
    if shielded:
        assert costs == 0 and interventions > 0
        assert (0 < edits <= interventions) == permissive
    else:
        assert costs > 0


def test_only_a_rule_with_edits_can_be_permissive() -> None:
    with pytest.raises(ValueError, match="has no edits"):
        ShieldWrapper(gym.make("SafePointCircle-v0"), "auto", permissive=True)


def test_unshielded_adversary_pays_so_the_test_above_can_fail() -> None:
    env = SafetyNavigationEnv("Point", "Goal", 1)
    env.reset(seed=1)
    costs = sum(env.step(toward_nearest(env, "hazard"))[4]["cost"] for _ in range(200))
    assert costs > 0


def test_an_observation_no_live_env_produced_fails_closed() -> None:
    rule = NavigationShieldingRule("Point", "Goal", 1)
    env = SafetyNavigationEnv("Point", "Goal", 1)
    obs, _ = env.reset(seed=0)
    with pytest.raises(ShieldFailure, match="cannot read its state"):
        rule.shield(obs[None] + 0.5, np.zeros((1, 2)))  # e.g. a normalised observation


def test_a_vec_env_of_several_envs_is_shielded_row_by_row() -> None:
    venv = DummyVecEnv([lambda: gym.make("sppo_sb3/SafetyPointGoal1-v0") for _ in range(3)])
    venv.seed(0)
    obs = venv.reset()
    rule = default_shielding_rule("sppo_sb3/SafetyPointGoal1-v0", venv)
    decision = rule.shield(obs, np.zeros((3, 2)))
    assert decision.actions.shape == (3, 2) and np.isfinite(decision.advantage).all()


def test_the_constraint_covers_only_what_the_level_constrains() -> None:
    def constraint(robot: str, task: str, level: int) -> NavigationConstraint:
        definition = navigation_task(robot, task, level)
        return NavigationConstraint.of(definition, shield_model(definition))

    goal1, goal2 = constraint("Point", "Goal", 1), constraint("Point", "Goal", 2)
    assert len(goal1.hazard_columns) == 8 and not goal1.contact_columns  # Goal1's vase costs nothing
    assert len(goal2.hazard_columns) == 10 and len(goal2.contact_columns) == 10
    assert (
        len(constraint("Point", "Push", 1).contact_columns) == 0 and len(constraint("Point", "Push", 2).contact_columns) == 4
    )
    assert constraint("Car", "Circle", 2).wall_both_axes and not constraint("Car", "Circle", 1).wall_both_axes
    assert len(constraint("Car", "Button", 1).button_columns) == 4 and constraint("Point", "Button", 1).goal_columns
    button2 = constraint("Point", "Button", 2)
    assert len(button2.gremlin_columns) == 6 and not button2.contact_columns  # its gremlins; its vase costs nothing
    with pytest.raises(ValueError, match="needs no shield"):
        NavigationShieldingRule("Point", "Goal", 0)


@pytest.mark.parametrize("algo", ["SPPO", "SAILR"])
def test_the_shielded_algorithms_find_the_rule_and_learn_behind_it(algo: str) -> None:
    settings = {"SPPO": {**TINY_SPPO, "learning_starts": 32}, "SAILR": {**TINY_SAILR, "n_steps": 64}}[algo]
    model = getattr(sppo_sb3, algo)("MlpPolicy", "sppo_sb3/SafetyPointGoal1-v0", shield="auto", seed=0, **settings)
    assert isinstance(model.shield_rule, NavigationShieldingRule)
    model.learn(128)
    assert model.safety_metrics.violations == 0
