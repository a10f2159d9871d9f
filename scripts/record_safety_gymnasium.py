"""Record reference fixtures from the original Safety-Gymnasium 1.0.0 navigation tasks (Point/Car × Goal/Button/Push/Circle).

The original needs Python 3.10 (mujoco 2.3.3, gymnasium 0.28.1, numpy 1.23.5); it lives in its own venv, and this
script imports nothing from ``sppo_sb3``::

    "$(pyenv prefix 3.10.13)/bin/python" -m venv /tmp/sg310 && /tmp/sg310/bin/pip install safety-gymnasium==1.0.0
    /tmp/sg310/bin/python scripts/record_safety_gymnasium.py [--out DIR] [--tasks SafetyPointGoal1 ...]
        [--steps 150] [--layout-seeds 0 1 2 3 4]

It writes one ``<out>/<EnvId without -v0>.npz`` per task (``np.savez_compressed``). Keys (T = steps recorded;
"before" = the state at the start of ``env.step(action[t])``, "after" = what that call returned or left behind):

``meta``
    0-d str array, JSON: ``versions``; ``env_id``; ``task_class``; ``timestep``; ``frameskip_binom_n``/``_p``
    (n mj_step per env step when p = 1); ``num_steps`` (episode length) and ``max_episode_steps`` (TimeLimit);
    ``T``; ``steps_requested``; ``lidar`` / ``compass`` (LidarConf / CompassConf); ``placements_extents``,
    ``placements_margin``, ``placements`` (name -> [rects or null, keepout]); ``obs_keys`` ([key, size] in the
    flattened order); ``body_names``, ``geom_names`` (id order), ``joints`` ([name, qposadr, dofadr, type]),
    ``mocap_bodies`` (mocap id order); ``agent`` (name, geom_names, actuators [name, ctrlrange], keepout,
    placements, rot, z_height, sensors); ``cost_keys`` (columns of ``cost_terms``, ``cost_sum`` last);
    ``objects`` (each object group's parameters: num, size, keepout, placements, locations, travel, costs ...);
    ``conf`` (reward/cost/mechanism/floor confs); ``reward_factor`` (Circle); ``task_scalars`` (names below);
    ``controller``; ``notes`` (facts about the original: RNG draws per step, cost semantics, warmstart, resets,
    mocaps; see ``NOTES``); ``layouts``: for each layout seed s, what ``env.reset(seed=s)`` produced: ``layout``
    (name -> xy), ``agent_rot``, ``world`` ({geoms, free_geoms, mocaps}: name -> its config, pos/rot/size/...),
    ``goal_pos``, ``goal_button`` (Button), ``obs``, ``qpos``, ``qvel``.
``qpos`` (T, nq), ``qvel`` (T, nv), ``qacc_warmstart`` (T, nv), ``time`` (T,), ``mocap_pos`` (T, nmocap, 3),
``mocap_quat`` (T, nmocap, 4)
    MjData before the step (nmocap may be 0).
``last_dist_goal``, ``last_dist_box``, ``last_box_goal``, ``buttons_timer``, ``goal_button`` (T,)
    the task's attributes before the step, where the task has them (Goal/Button/Push; Push; Push; Button; Button).
``goal_pos`` (T, 3)
    ``data.body('goal').xpos`` before the step (not Circle: it has no goal).
``action`` (T, act_dim)
    the action passed to ``env.step`` (already inside the ctrlrange).
``obs`` (T, obs_dim), ``reward`` (T,), ``cost`` (T,), ``terminated``, ``truncated``, ``goal_met`` (T,) bool
    ``env.step``'s returns; ``cost`` is ``info['cost_sum']``; ``goal_met`` is ``info.get('goal_met', False)``.
``goal_pos_after`` (T, 3), ``goal_button_after`` (T,)
    the goal (and the goal button, Button) after the step, i.e. after any resampling.
``cost_terms`` (T, len(cost_keys))
    ``info[k]`` for k in ``meta['cost_keys']``; a key absent from that step's info is 0 (Buttons omit
    ``cost_buttons`` while their timer runs).
``rng_steps`` (n,), ``rng_keys`` (n, 624) uint32, ``rng_pos`` (n,)
    for the steps where the goal was met: the task's ``np.random.RandomState`` state (MT19937) before the step.
``rng_reset_keys`` (624,) uint32, ``rng_reset_pos`` ()
    that state right after ``env.reset(seed=0)``.
``qpos_final`` (nq,), ``qvel_final`` (nv,)
    MjData after the last recorded step.

Every recorded reset follows a throwaway ``env.reset(seed=0)`` (see ``NOTES['reset']``). The rollout starts from
``env.reset(seed=0)`` and is driven by a steering controller (own ``np.random.default_rng(1234)``: Gaussian noise 0.3,
and 20% uniformly random actions), see :func:`control`; T is ``--steps`` (default 150, or ``STEPS[task]``) unless the
episode ends first. The total size is printed (the fixtures are meant to stay under 3 MB).
"""

from __future__ import annotations

import argparse
import json
import platform
from pathlib import Path

import gymnasium
import mujoco
import numpy as np
import safety_gymnasium

ROBOTS = ("Point", "Car")
TASKS = tuple(f"Safety{r}{k}{lvl}" for r in ROBOTS for k in ("Goal", "Button", "Push", "Circle") for lvl in (0, 1, 2))
SCALARS = {
    "goal": ("last_dist_goal",),
    "button": ("last_dist_goal", "buttons_timer", "goal_button"),
    "push": ("last_dist_goal", "last_dist_box", "last_box_goal"),
    "circle": (),
}
STEPS = {"SafetyPointPush1": 230}  # default --steps per task where 150 is too few for a goal_met
GAIN_FWD, GAIN_SPEED, GAIN_TURN, NOISE, P_RANDOM, PUSH_BEHIND = 3.0, 1.0, 2.0, 0.3, 0.2, 0.25
NOTES = {
    "rng": "every env.step first draws binomial(frameskip_binom_n, p) from the task RandomState (p = 1: always n, "
    "but it consumes one double = 2 uint32); a goal resampling then draws from the same RandomState",
    "cost": "cost_conf.constrain_indicator: each info cost_* is float(raw > 0); cost_sum is computed from the raw "
    "terms and then also made an indicator, so cost = info[cost_sum] is 0 or 1",
    "warmstart": "mujoco 2.3.3 mj_forward copies qacc into qacc_warmstart, and the original calls mj_forward "
    "several times per step (after the frames, in the cost, in obs, on goal resampling)",
    "reset": "all resets recorded follow a throwaway env.reset(seed=0): the first reset after make() makes another "
    "number of mj_forward calls, and mj_kinematics (2.3.3) renormalises free-joint quaternions in qpos in "
    "place, flipping their last bit at each call; the Car starts exactly touching the floor (contact dist "
    "~ -1e-17), so that toggles its floor contacts and its reset accelerometer z by ~9.5",
    "mocap": "gremlin mocap bodies sit at the origin at reset (their geoms carry the layout offset); before every "
    "mj_step Gremlins.move sets every mocap_pos to (travel sin(time), travel cos(time), size)",
}


def jsonable(x):
    """Recursively turn numpy values (and tuples, dataclass confs) into plain JSON values."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, np.generic):
        return x.item()
    if hasattr(x, "__dataclass_fields__"):
        return jsonable(vars(x))
    return x


def kind_of(task) -> str:
    """'goal', 'button', 'push' or 'circle', from the task class name (e.g. GoalLevel1)."""
    return type(task).__name__.split("Level")[0].lower()


def scalar(task, name: str) -> float:
    """One task scalar by its recorded name."""
    if name == "buttons_timer":
        return float(task.buttons.timer)
    if name == "goal_button":
        return float(task.buttons.goal_button)
    return float(getattr(task, name))


def object_params(task) -> dict:
    """Each object group's parameters (all its attributes but the engine/agent/RNG handles)."""
    skip = {"engine", "agent", "random_generator"}
    return {o.name: {k: v for k, v in vars(o).items() if k not in skip} for o in task._obstacles}


def static_meta(env, task) -> dict:
    """Everything about the task that does not depend on the seed (call after a reset)."""
    m, agent = task.model, task.agent
    spaces = task.obs_info.obs_space_dict.spaces
    return {
        "versions": {
            "safety_gymnasium": safety_gymnasium.__version__,
            "mujoco": mujoco.__version__,
            "gymnasium": gymnasium.__version__,
            "numpy": np.__version__,
            "python": platform.python_version(),
        },
        "env_id": env.spec.id,
        "task_class": type(task).__name__,
        "timestep": m.opt.timestep,
        "frameskip_binom_n": task.sim_conf.frameskip_binom_n,
        "frameskip_binom_p": task.sim_conf.frameskip_binom_p,
        "num_steps": task.num_steps,
        "max_episode_steps": env.spec.max_episode_steps,
        "lidar": vars(task.lidar_conf),
        "compass": vars(task.compass_conf),
        "placements_extents": task.placements_conf.extents,
        "placements_margin": task.placements_conf.margin,
        "placements": task.placements_conf.placements,
        "obs_keys": [[k, int(np.prod(s.shape))] for k, s in spaces.items()],
        "body_names": [m.body(i).name for i in range(m.nbody)],
        "geom_names": [m.geom(i).name for i in range(m.ngeom)],
        "joints": [[m.joint(i).name, m.jnt_qposadr[i], m.jnt_dofadr[i], m.jnt_type[i]] for i in range(m.njnt)],
        "mocap_bodies": sorted(
            (m.body(i).name for i in range(m.nbody) if m.body_mocapid[i] >= 0),
            key=lambda name: m.body_mocapid[m.body(name).id],
        ),
        "agent": {
            "name": type(agent).__name__,
            "geom_names": agent.body_info.geom_names,
            "actuators": [[m.actuator(i).name, m.actuator_ctrlrange[i]] for i in range(m.nu)],
            "keepout": agent.keepout,
            "placements": agent.placements,
            "locations": agent.locations,
            "rot": agent.rot,
            "z_height": agent.z_height,
            "sensor_conf": agent.sensor_conf,
        },
        "objects": object_params(task),
        "conf": {
            "reward": task.reward_conf,
            "cost": task.cost_conf,
            "mechanism": task.mechanism_conf,
            "floor": task.floor_conf,
            "action_noise": task.action_noise,
        },
        "reward_factor": getattr(task, "reward_factor", None),
        "task_scalars": list(SCALARS[kind_of(task)]),
        "controller": {
            "seed": 1234,
            "gain_fwd": GAIN_FWD,
            "gain_speed": GAIN_SPEED,
            "gain_turn": GAIN_TURN,
            "noise_std": NOISE,
            "p_random": P_RANDOM,
            "push_behind": PUSH_BEHIND,
        },
        "notes": NOTES,
    }


def layout_record(env, task, seed: int) -> dict:
    """What ``env.reset(seed=seed)`` produced: layout, world config, goal, initial obs and MjData state."""
    obs, _ = env.reset(seed=seed)
    wc = task.world_info.world_config_dict
    rec = {
        "seed": seed,
        "layout": task.world_info.layout,
        "agent_rot": wc["agent_rot"],
        "world": {k: wc[k] for k in ("geoms", "free_geoms", "mocaps")},
        "obs": obs,
        "qpos": task.data.qpos,
        "qvel": task.data.qvel,
    }
    if kind_of(task) != "circle":
        rec["goal_pos"] = task.goal.pos
    if kind_of(task) == "button":
        rec["goal_button"] = task.buttons.goal_button
    return jsonable(rec)


def heading_error(task, target_xy: np.ndarray) -> tuple[float, float, float]:
    """Distance to an XY target, its angle from the robot's forward axis (+x Point, -y Car; CCW positive), and the
    robot's forward speed."""
    mat = task.agent.mat
    ego, vel = (np.r_[target_xy, 0.0] - task.agent.pos) @ mat, task.agent.vel @ mat
    if type(task.agent).__name__ == "Car":
        return float(np.hypot(ego[0], ego[1])), float(np.arctan2(ego[0], -ego[1])), float(-vel[1])
    return float(np.hypot(ego[0], ego[1])), float(np.arctan2(ego[1], ego[0])), float(vel[0])


def target_of(task, state: dict) -> np.ndarray:
    """The controller's XY target: goal, goal button, a point behind the box then the goal, or ahead on the circle."""
    kind, agent_xy = kind_of(task), task.agent.pos[:2]
    if kind == "goal":
        return task.goal.pos[:2]
    if kind == "button":
        return task.buttons.pos[task.buttons.goal_button][:2]
    if kind == "push":
        return push_target(task, agent_xy, state)
    phi = np.arctan2(agent_xy[1], agent_xy[0]) + 0.6
    return task.circle.radius * np.array([np.cos(phi), np.sin(phi)])


def push_target(task, agent_xy: np.ndarray, state: dict) -> np.ndarray:
    """Push: around the box (if in front of it) to a point behind it, seen from the goal; then into the box.

    ``state['pushing']`` (hysteresis) starts in the corridor behind the box (|across| < 0.15) and lasts until the
    robot is 0.3 off the line or level with the box.
    """
    box, goal, size = task.push_box.pos[:2], task.goal.pos[:2], task.push_box.size
    u = (goal - box) / (np.linalg.norm(goal - box) + 1e-9)
    n = np.array([-u[1], u[0]])
    along, across = float((agent_xy - box) @ u), float((agent_xy - box) @ n)
    behind = 2 * size + PUSH_BEHIND
    limit = 0.3 if state.get("pushing") else 0.15
    state["pushing"] = along < -size and abs(across) < limit
    if state["pushing"]:  # toward the goal through the box, pulled back to the line
        return box + 0.3 * u - 3.0 * across * n
    if along < -0.4 * behind:  # behind the box: the point behind it
        return box - behind * u
    return box + (1.0 if across >= 0 else -1.0) * behind * n - 0.6 * behind * u  # beside/in front: go round


def control(task, rng: np.random.Generator, state: dict) -> np.ndarray:
    """Steer toward :func:`target_of`, add N(0, 0.3) noise; with probability 0.2 a uniform random action instead.

    A target well behind the robot (cos < -0.3) is reached in reverse. The draws per step are fixed: one uniform
    (the 20% switch), act_dim normals, act_dim uniforms.
    """
    dist, ang, speed = heading_error(task, target_of(task, state))
    sign = -1.0 if np.cos(ang) < -0.3 else 1.0
    if sign < 0:  # the angle from the backward axis
        ang = float(np.angle(-np.exp(1j * ang)))
    fwd = np.clip(sign * GAIN_FWD * dist * max(np.cos(ang), 0.0) - GAIN_SPEED * speed, -1.0, 1.0)
    turn = np.clip(GAIN_TURN * ang, -1.0, 1.0)
    action = np.array([fwd + turn, fwd - turn] if type(task.agent).__name__ == "Car" else [fwd, turn])
    switch, noise, uniform = rng.random(), rng.normal(0.0, NOISE, action.shape), rng.uniform(-1.0, 1.0, action.shape)
    low, high = task.action_space.low, task.action_space.high
    return np.clip(uniform if switch < P_RANDOM else action + noise, low, high).astype(np.float64)


def cost_keys(env, task, infos: list[dict]) -> list[str]:
    """cost_* keys: those of the reset's cost dict, then any others seen in the rollout, ``cost_sum`` last."""
    keys = [k for k in env.unwrapped.cost if k != "cost_sum"]
    for info in infos:
        keys += [k for k in info if k.startswith("cost_") and k != "cost_sum" and k not in keys]
    return [*keys, "cost_sum"]


def rollout(env, task, steps: int) -> tuple[dict, list[str], np.ndarray]:
    """Run the controller from ``env.reset(seed=0)``; return the per-step arrays, the cost keys and the reset obs."""
    obs0, _ = env.reset(seed=0)
    rs, rng = task.random_generator.random_generator, np.random.default_rng(1234)
    kind, d = kind_of(task), task.data
    state = rs.get_state()
    assert state[3] == 0, "RandomState holds a cached gaussian"
    out = {
        k: []
        for k in (
            "qpos",
            "qvel",
            "qacc_warmstart",
            "time",
            "mocap_pos",
            "mocap_quat",
            "action",
            "obs",
            "reward",
            "cost",
            "terminated",
            "truncated",
            "goal_met",
            "rng_steps",
            "rng_keys",
            "rng_pos",
        )
    }
    out.update({"rng_reset_keys": state[1], "rng_reset_pos": np.int64(state[2])})
    infos, controller_state = [], {}
    for t in range(steps):
        for k in ("qpos", "qvel", "qacc_warmstart", "time", "mocap_pos", "mocap_quat"):
            out[k].append(np.array(getattr(d, k), dtype=np.float64))
        for name in SCALARS[kind]:
            out.setdefault(name, []).append(scalar(task, name))
        if kind != "circle":
            out.setdefault("goal_pos", []).append(task.goal.pos)
        action = control(task, rng, controller_state)
        state = rs.get_state()
        obs, reward, cost, term, trunc, info = env.step(action)
        met = bool(info.get("goal_met", False))
        for k, v in zip(
            ("action", "obs", "reward", "cost", "terminated", "truncated", "goal_met"),
            (action, obs, reward, cost, term, trunc, met),
        ):
            out[k].append(v)
        if kind != "circle":
            out.setdefault("goal_pos_after", []).append(task.goal.pos)
        if kind == "button":
            out.setdefault("goal_button_after", []).append(float(task.buttons.goal_button))
        if met:
            out["rng_steps"].append(t), out["rng_keys"].append(state[1]), out["rng_pos"].append(state[2])
        infos.append(info)
        if term or trunc:
            break
    keys = cost_keys(env, task, infos)
    out["cost_terms"] = [[float(info.get(k, 0.0)) for k in keys] for info in infos]
    arrays = {k: np.asarray(v, dtype=np.float64) for k, v in out.items()}
    for k in ("terminated", "truncated", "goal_met"):
        arrays[k] = arrays[k].astype(bool)
    arrays["rng_steps"] = arrays["rng_steps"].astype(np.int64)
    arrays["rng_pos"] = arrays["rng_pos"].astype(np.int64)
    arrays["rng_reset_pos"] = arrays["rng_reset_pos"].astype(np.int64)
    arrays["rng_keys"] = np.asarray(out["rng_keys"], dtype=np.uint32).reshape(-1, 624)
    arrays["rng_reset_keys"] = np.asarray(out["rng_reset_keys"], dtype=np.uint32)
    n = len(infos)
    arrays["mocap_pos"] = arrays["mocap_pos"].reshape(n, -1, 3)
    arrays["mocap_quat"] = arrays["mocap_quat"].reshape(n, -1, 4)
    arrays["qpos_final"], arrays["qvel_final"] = d.qpos.copy(), d.qvel.copy()
    return arrays, keys, obs0


def record_task(name: str, steps: int, seeds: list[int], out_dir: Path) -> dict:
    """Record one task's fixture file and return a summary row."""
    env = safety_gymnasium.make(f"{name}-v0")
    task = env.unwrapped.task
    env.reset(seed=0)  # a throwaway first reset: see NOTES['reset']
    layouts = [layout_record(env, task, s) for s in seeds]
    meta = static_meta(env, task)
    arrays, keys, obs0 = rollout(env, task, steps)
    if 0 in seeds:  # the layout of seed 0 is the rollout's start
        assert np.array_equal(layouts[seeds.index(0)]["obs"], obs0.tolist())
    meta.update({"layouts": layouts, "cost_keys": keys, "T": len(arrays["reward"]), "steps_requested": steps})
    assert arrays["obs"].shape[1] == sum(n for _, n in meta["obs_keys"])
    path = out_dir / f"{name}.npz"
    np.savez_compressed(path, meta=np.array(json.dumps(jsonable(meta))), **arrays)
    env.close()
    return {
        "task": name,
        "obs_dim": arrays["obs"].shape[1],
        "T": meta["T"],
        "goal_met": int(arrays["goal_met"].sum()),
        "cost": float(arrays["cost"].sum()),
        "bytes": path.stat().st_size,
    }


def main() -> None:
    """Parse the CLI, record every task, print the summary table and the total size."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("tests/envs/data/navigation"))
    parser.add_argument("--tasks", nargs="+", default=list(TASKS), help="env ids without -v0")
    parser.add_argument("--steps", type=int, default=None, help="steps per task (default 150, more for those in STEPS)")
    parser.add_argument("--layout-seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    print(f"{'task':24s} {'obs':>4s} {'T':>4s} {'goal_met':>8s} {'cost':>7s} {'bytes':>8s}")
    for name in args.tasks:
        name = name.removesuffix("-v0")
        row = record_task(name, args.steps or STEPS.get(name, 150), args.layout_seeds, args.out)
        rows.append(row)
        print(
            f"{row['task']:24s} {row['obs_dim']:4d} {row['T']:4d} {row['goal_met']:8d} {row['cost']:7.1f} {row['bytes']:8d}",
            flush=True,
        )
    total = sum(p.stat().st_size for p in args.out.glob("*.npz"))
    print(
        f"total size of {args.out}/*.npz: {total} bytes ({total / 2**20:.2f} MiB)"
        + (" -- OVER the 3 MB budget" if total > 3_000_000 else "")
    )
    print("tasks with cost > 0:", ", ".join(r["task"] for r in rows if r["cost"] > 0) or "none")


if __name__ == "__main__":
    main()
