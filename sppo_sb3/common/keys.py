"""Every key the package writes: into a step's ``info`` dict, and into the SB3 logger (TensorBoard, ``progress.csv``).

One home for the names, so that the envs, the shield, the algorithms, the zoo and the benchmark's readers agree.
The module imports nothing and sits on the ground floor: everything may import it.
"""

# ---------------------------------------------------------------------------------------------- a step's info dict
#: the violation indicator ``c(s, a)`` of Definition 1: 1.0 on the step that enters the unsafe set, else 0.0
COST_KEY = "cost"
#: the shaped cost ``ĉ`` of eq. 18 (what a learned shielding rule is fitted on)
SHAPED_COST_KEY = "shaped_cost"
#: ``SafeHalfCheetahHeight-v1``: the height of the front thigh after the step
HEIGHT_KEY = "fthigh_height"
#: the velocity tasks (``sppo_sb3/Safety<Robot>Velocity-v1``): the step's constrained velocity (x velocity, or xy speed)
VELOCITY_KEY = "velocity"
#: the shield replaced the proposal by the backup's action (eq. 12)
INTERVENED_KEY = "shield_intervened"
#: the action the learner proposed
PROPOSED_ACTION_KEY = "proposed_action"
#: the action the env executed (the proposal, or the backup's)
EXECUTED_ACTION_KEY = "executed_action"
#: ``Ā(s, a)`` of the proposal (eq. 5)
ADVANTAGE_KEY = "shield_advantage"
#: ``ShieldWrapper(on_intervention="terminate")`` turned the intervention into an absorbing terminal (eq. 7)
ABSORBED_KEY = "shield_absorbed"
#: the env's own reward of a step whose learner saw another (``R̃``, or the reward less the penalty)
ENV_REWARD_KEY = "env_reward"
#: under an action repeat (:mod:`~sppo_sb3.common.action_repeat`): the env steps the held action ran for
ENV_STEPS_KEY = "env_steps"
#: under an action repeat: how many of those env steps had ``info["cost"] > 0`` (``info["cost"]`` is their sum)
COSTLY_STEPS_KEY = "costly_steps"
#: under an action repeat: how many of those env steps the shield replaced the held action
INTERVENTIONS_KEY = "shield_interventions"
#: on how many env steps of the step the shield's replacement was an edit (an accepted action near the proposal) rather
#: than the backup's: a permissive rule's (they are among ``info["shield_interventions"]``)
EDITS_KEY = "shield_edits"
#: on the step that ends an episode: the sum of its ``info["cost"]`` (a ``monitor.csv`` column)
EPISODE_COST_INFO_KEY = "episode_cost"
#: on the step that ends an episode: its steps with ``info["cost"] > 0`` (a ``monitor.csv`` column)
EPISODE_VIOLATIONS_INFO_KEY = "episode_violations"
#: on the step that ends an episode: its steps where a shield replaced the action (NaN: no shield reported any)
EPISODE_INTERVENTIONS_INFO_KEY = "episode_interventions"
#: the extra ``monitor.csv`` columns, as ``Monitor(info_keywords=...)`` takes them
COST_INFO_KEYWORDS: tuple[str, ...] = (EPISODE_COST_INFO_KEY, EPISODE_VIOLATIONS_INFO_KEY, EPISODE_INTERVENTIONS_INFO_KEY)

# ---------------------------------------------------------------------------------------------- the SB3 logger
#: prefix of the safety metrics of Section V-B (:class:`~sppo_sb3.common.safety.SafetyMetrics`)
SAFETY_LOG_PREFIX = "safety/"
#: the measured episode cost ``J_C`` that the constrained algorithms compare with their cost limit
EPISODE_COST_ESTIMATE_LOG_KEY = "safety/ep_cost_estimate"
#: the Lagrange multiplier of the primal-dual algorithms (PDO, CSC, SACLag)
LAGRANGE_MULTIPLIER_LOG_KEY = "train/lagrange_multiplier"
#: prefix of the training statistics, as SB3's algorithms log them (SACLag's ``train/actor_loss``, ``train/cost_q``, ...)
TRAIN_LOG_PREFIX = "train/"
#: gradient updates so far, as SB3's algorithms log it (left out of TensorBoard)
N_UPDATES_LOG_KEY = "train/n_updates"
#: the evaluation callback's cost figures, beside SB3's ``eval/mean_reward``
EVAL_MEAN_COST_LOG_KEY = "eval/mean_cost"
EVAL_MEAN_VIOLATIONS_LOG_KEY = "eval/mean_violations"
EVAL_SAFE_EPISODE_RATE_LOG_KEY = "eval/safe_episode_rate"
#: the two deployments of the learned policy after training (Corollary 1), as ``<prefix>/<figure>``
DEPLOYMENT_SHIELDED = "eval"
DEPLOYMENT_UNSHIELDED = "eval_unshielded"
