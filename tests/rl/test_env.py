"""The RL environments: the Gymnasium and PettingZoo conformance checks, seeds, invalid actions."""

from __future__ import annotations

import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from pettingzoo.test import parallel_api_test, parallel_seed_test
from support import ROOT, base_mission
from support import rl as rl_support

from guadal_cli.errors import GuadalError
from guadal_cli.mission import prepare_dict
from guadal_cli.rl import MissionParallelEnv
from guadal_cli.rl.observation import COMPASS
from guadal_cli.runner import MissionRunner


def small(**overrides):
    """The paper lake, three boats, a short budget: a couple of dozen steps."""
    mission = base_mission(**overrides)
    mission["fleet"]["max_distance"] = 60.0
    return mission


@pytest.mark.parametrize("layout", ["image", "vector", "dict"])
def test_the_parallel_env_passes_pettingzoo_s_api_test(layout):
    parallel_api_test(MissionParallelEnv(small(), layout=layout), num_cycles=200)


def test_a_target_mode_env_passes_pettingzoo_s_api_test():
    mission = small(algorithm={"type": "random", "mode": "target"})
    parallel_api_test(MissionParallelEnv(mission), num_cycles=50)


@pytest.mark.parametrize(
    "layout, mode", [("image", "sequential"), ("dict", "sequential"), ("vector", "target")]
)
def test_the_gymnasium_env_passes_check_env(layout, mode):
    mission = small(algorithm={"type": "random", "mode": mode})
    env = gymnasium.make("guadal/Mission-v0", mission=mission, layout=layout, render_mode="rgb_array")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a warning from the checker is a failure here
        check_env(env.unwrapped)
    assert isinstance(env.action_space, gymnasium.spaces.MultiDiscrete)
    n_actions = len(COMPASS) if mode == "sequential" else env.unwrapped.parallel.prep.graph.n_nodes
    assert list(env.action_space.nvec) == [n_actions] * 3


def test_the_gymnasium_env_is_made_from_a_mission_file():
    env = gymnasium.make("guadal/Mission-v0", mission=ROOT / "missions" / "lake_greedy.yaml")
    obs, info = env.reset(seed=3)
    assert obs.shape == (3, 7, 30, 49) and obs.dtype == np.float32
    assert info["action_mask"].shape == (3, 9)


def rollout(env, seed, policy_seed=0, steps=400):
    """Observations and rewards of a seeded random (masked) rollout."""
    rng = np.random.default_rng(policy_seed)
    obs, infos = env.reset(seed=seed)
    trace = [np.stack(list(obs.values()))]
    rewards = []
    for _ in range(steps):
        if not env.agents:
            break
        actions = {a: int(rng.choice(np.flatnonzero(infos[a]["action_mask"]))) for a in env.agents}
        obs, reward, _, _, infos = env.step(actions)
        if obs:
            trace.append(np.stack(list(obs.values())))
        rewards.append(tuple(reward.values()))
    return trace, rewards


def test_same_seed_same_observations_and_rewards():
    env = MissionParallelEnv(small())
    a_obs, a_rew = rollout(env, seed=11)
    b_obs, b_rew = rollout(MissionParallelEnv(small()), seed=11)
    assert a_rew == b_rew and len(a_rew) > 5
    assert all(np.array_equal(x, y) for x, y in zip(a_obs, b_obs))
    c_obs, c_rew = rollout(env, seed=12)  # another world: the model's mean differs from the start
    assert not np.array_equal(a_obs[1][:, 2], c_obs[1][:, 2]) or a_rew != c_rew


def test_pettingzoo_s_seed_test_passes():
    parallel_seed_test(lambda: MissionParallelEnv(small()), num_cycles=50)


def test_the_default_gp_reward_is_the_fall_of_the_mean_std():
    env = MissionParallelEnv(small())
    env.reset(seed=1)
    before = env.episode.environment.metrics()["mean_std"]
    _, rewards, *_ = env.step({a: 3 for a in env.agents})  # everyone east (if they can)
    after = env.episode.environment.metrics()["mean_std"]
    assert rewards["boat_0"] == pytest.approx(before - after) and rewards["boat_0"] > 0


def test_invalid_actions_never_raise_the_boat_stays_and_pays():
    mission = small()
    mission["fleet"]["initial_positions"] = [0, 100, 200]  # node 0: the first water cell of the top row
    env = MissionParallelEnv(mission, invalid_penalty=0.5)
    _, infos = env.reset(seed=2)
    assert infos["boat_0"]["action_mask"][COMPASS.index("N")] == 0  # north of boat 0 is land
    before = dict(env.episode.fleet.positions)
    bad = {"boat_0": COMPASS.index("N"), "boat_1": 99, "boat_2": "east"}  # land, and no such actions
    _, rewards, _, _, infos = env.step(bad)
    assert env.episode.fleet.positions == before  # nobody moved
    for a in bad:
        assert "invalid" in infos[a] and rewards[a] == pytest.approx(-0.5)


def _independent_moves(env, infos, rng) -> dict:
    """Random valid moves, each boat to a node no boat stands on or is sent to: then no boat's
    move depends on another's, and staying instead changes nothing but its own samples."""
    positions = env.episode.fleet.positions
    for _ in range(500):
        actions = {a: int(rng.choice(np.flatnonzero(infos[a]["action_mask"][1:]) + 1)) for a in env.agents}
        nodes = [int(env.builder.action_nodes[positions[env.vehicle(a)], act]) for a, act in actions.items()]
        if len(set(nodes)) == len(nodes) and not set(nodes) & set(positions.values()):
            return actions
    raise AssertionError("no independent moves found")


@pytest.mark.parametrize("seed", [4, 9])
def test_difference_credit_pays_each_boat_what_its_own_samples_added(seed):
    """Checked against the world where that boat stayed instead (no sensor noise, a static
    field, moves that cannot interfere): there, the fleet's reward is the counterfactual."""
    mission = small()
    mission["fleet"]["max_distance"] = 200.0
    rng = np.random.default_rng(seed)
    env = MissionParallelEnv(mission, credit="difference")
    _, infos = env.reset(seed=seed)
    history, paid = [], 0
    for _ in range(5):
        actions = _independent_moves(env, infos, rng)
        _, rewards, _, _, infos = env.step(actions)
        for agent in actions:
            stayed = MissionParallelEnv(mission)  # team credit: every boat gets the fleet's reward
            stayed.reset(seed=seed)
            for earlier in history:
                stayed.step(earlier)
            _, without, *_ = stayed.step({**actions, agent: COMPASS.index("stay")})
            team = infos[agent]["team_reward"]
            assert rewards[agent] == pytest.approx(team - without[agent], abs=1e-12)
            assert rewards[agent] < team  # its teammates' samples are not its own
            paid += rewards[agent] > 0
        history.append(actions)
    assert paid >= 10  # a new sample of an uncertain field is worth something
    # a boat that takes no sample adds nothing, whatever the others do
    actions = {**_independent_moves(env, infos, rng), "boat_1": COMPASS.index("stay")}
    _, rewards, _, _, infos = env.step(actions)
    assert rewards["boat_1"] == 0.0 and infos["boat_1"]["team_reward"] > 0


@pytest.mark.parametrize("environment", ["trash", "oil_spill"])
def test_difference_credit_passes_pettingzoo_s_api_and_seed_tests_on_evolving_worlds(environment):
    mission = small(environment={"type": environment}, algorithm={"type": "random"})
    parallel_api_test(MissionParallelEnv(mission, credit="difference"), num_cycles=50)
    parallel_seed_test(lambda: MissionParallelEnv(mission, credit="difference"), num_cycles=20)


def test_an_unknown_credit_is_one_sentence():
    with pytest.raises(GuadalError) as info:
        MissionParallelEnv(small(), credit="individual")
    assert "credit must be one of team, difference" in str(info.value) and "\n" not in str(info.value)
    with pytest.raises(GuadalError) as info:  # one agent: nothing to share out, not silently ignored
        gymnasium.make("guadal/Mission-v0", mission=small(), credit="difference")
    assert "one agent, the fleet" in str(info.value) and "\n" not in str(info.value)


@pytest.mark.parametrize("reward", ["iou", "nonsense"])
def test_a_reward_the_environment_cannot_give_is_one_sentence(reward):
    with pytest.raises(GuadalError) as info:
        MissionParallelEnv(small(), reward=reward)
    assert "reward" in str(info.value) and "\n" not in str(info.value)


def test_a_few_hundred_steps_of_a_learning_loop():
    """RL smoke test: REINFORCE-style updates of a linear policy over a few hundred agent-steps."""
    env = MissionParallelEnv(small(), layout="vector")
    size = env.observation_space("boat_0").shape[0]
    rng = np.random.default_rng(0)
    w = np.zeros((size, 9))
    steps = 0
    while steps < 300:
        obs, infos = env.reset()
        grads, total = [], 0.0
        while env.agents:
            actions = {}
            for a in env.agents:
                logits = obs[a] @ w
                logits[infos[a]["action_mask"] == 0] = -np.inf
                p = np.exp(logits - logits.max())
                p /= p.sum()
                actions[a] = int(rng.choice(9, p=p))
                grads.append(np.outer(obs[a], np.eye(9)[actions[a]] - p))
            obs, rewards, _, _, infos = env.step(actions)
            total += sum(rewards.values())
            steps += len(actions)
        w += 0.1 * total * np.mean(grads, axis=0)
    assert np.isfinite(w).all() and np.abs(w).sum() > 0


def test_a_policy_sees_the_same_inputs_in_training_and_in_guadal_run(tmp_path):
    """The env and the policy planner build observations in one module: played by the same
    policy, they show it identical arrays at every decision and end on the same nodes."""
    mission = small(algorithm={"type": "policy", "model": "support.rl:recording_std_ahead"})
    mission["output"] = {"directory": str(tmp_path), "database": "none"}
    prep = prepare_dict(mission, tmp_path)
    rl_support.SEEN.clear()  # validation called it once on a blank batch
    MissionRunner(prep, output=tmp_path / "run").run()
    deployed = list(rl_support.SEEN)
    env = MissionParallelEnv(mission)
    obs, infos = env.reset(seed=mission["seed"])
    trained = []
    while env.agents:
        batch = np.stack([obs[a] for a in env.agents])
        trained.append(batch)
        scores = rl_support.std_ahead(batch)
        actions = {
            a: int(np.argmax(np.where(infos[a]["action_mask"] > 0, s, -np.inf)))
            for a, s in zip(env.agents, scores)
        }
        obs, _, _, _, infos = env.step(actions)
    assert len(trained) > 5
    assert len(deployed) == len(trained)
    for shown_in_training, shown_deployed in zip(trained, deployed):
        assert np.array_equal(shown_in_training, shown_deployed)
