"""An agent in one call (trainers.agent.load_agent) on the committed checkpoints: it drives as
the evaluator drives, in TorchRL and in Gymnasium."""

from pathlib import Path

import numpy as np
import pytest
import torch

from torchpark.sim.vehicle import gear_travel
from trainers.agent import load_agent
from trainers.evaluate import checkpoint_agent, run_level

ROOT = Path(__file__).resolve().parents[1]
# The policy alone (position and goal/clearance features in its input, power and gear action
# maps) and the hybrid of the fast preset (brake, docking law, 5-step action repeat, the
# brake's flag in its input).
CHECKPOINTS = [ROOT / "results" / "policy_alone" / "checkpoint_best.pt",
               ROOT / "results" / "fast" / "checkpoint_final.pt"]


def _gym_episode(agent, occupancy: float, seed: int):
    """One Gymnasium episode driven by ``agent.predict`` (its state passed back, as SB3's
    recurrent predict: None for an agent without gear features or scan memory): the
    rear-axle poses after each step (from the reset on) and the last info."""
    env = agent.gym_env(occupancy=occupancy, seed=seed)
    obs, info = env.reset()
    base = env.unwrapped.env
    poses = [base.state.pose[0].clone()]
    terminated = truncated = False
    state = None
    while not (terminated or truncated):
        action, state = agent.predict(obs, info, state=state)
        recurrent = bool({"gear", "scan_memory"} & set(agent.config.agent.features))
        assert (state is None) == (not recurrent)
        assert action.shape == (2,) and np.abs(action).max() <= 1
        obs, _, terminated, truncated, info = env.step(action)
        poses.append(base.state.pose[0].clone())
    return torch.stack(poses), info


@pytest.mark.slow
@pytest.mark.parametrize("path", CHECKPOINTS, ids=lambda p: p.parent.name)
def test_load_agent_reproduces_the_evaluators_first_episode(path):
    occupancy, seed = 0.6, 5
    evaluated = run_level(checkpoint_agent(str(path)), occupancy, episodes=1, seed=seed)
    length = int(evaluated.length[0])
    agent = load_agent(str(path))
    # TorchRL: the evaluator's env and the policy, in env.rollout.
    rollout = agent.make_env(1, occupancy, seed).rollout(1000, agent.policy)
    assert rollout.shape[-1] == length
    assert bool(rollout["next", "success"][0, -1]) == bool(evaluated.success[0])
    # Gymnasium: the same lot from the same seed, the same trajectory to the last bit.
    poses, info = _gym_episode(agent, occupancy, seed)
    assert info["success"] == bool(evaluated.success[0])
    assert info["collision"] == bool(evaluated.collision[0])
    torch.testing.assert_close(poses, evaluated.poses[:len(poses), 0], rtol=0, atol=0)
    assert len(poses) == length + 1


def test_predict_takes_a_batch_and_names_what_it_needs():
    agent = load_agent(str(CHECKPOINTS[0]))
    env = agent.gym_env(seed=0)
    obs, info = env.reset()
    with pytest.raises(ValueError, match=r"info\['position'\]"):
        agent.predict(obs)  # this policy reads the car's position, which info carries
    with pytest.raises(ValueError, match=r"observation must have shape \(23,\)"):
        agent.predict(obs[:22], info)
    with pytest.raises(ValueError, match="one value per observation"):
        agent.predict(np.stack([obs, obs]), info)  # one observation's info for two
    batch = np.stack([obs, obs, obs])
    actions, _ = agent.predict(batch, {"position": np.stack([info["position"]] * 3)})
    assert actions.shape == (3, 2)
    np.testing.assert_allclose(actions[0], agent.predict(obs, info)[0], atol=1e-5)  # matmul
    sampled, _ = agent.predict(batch, {"position": np.stack([info["position"]] * 3)},
                               deterministic=False)
    assert not np.array_equal(sampled, actions) and np.abs(sampled).max() <= 1


def test_predict_refuses_what_it_would_misread():
    agent = load_agent(str(CHECKPOINTS[0]))
    obs, info = agent.gym_env(seed=0).reset()
    with pytest.raises(ValueError, match="observation must be a real array"):
        agent.predict(obs.astype(np.complex64), info)  # its imaginary part would be dropped
    with pytest.raises(ValueError, match="observation must be finite"):
        agent.predict(np.full_like(obs, np.nan), info)
    with pytest.raises(TypeError, match="deterministic must be a bool"):
        agent.predict(obs, info, deterministic="no")


def rows_predict_as_alone(agent, going_obs, fresh_obs, info, state):
    """A batch of two rows, the first going on from ``state``, the second flagged by
    episode_start as a new episode's first (both at ``info``'s position): each row's action
    and state are those it gets alone. Returns the single predictions (going on, fresh)."""
    batch = np.stack([going_obs, fresh_obs])
    pos = {"position": np.stack([info["position"]] * 2)}
    actions, states = agent.predict(batch, pos, state=np.stack([state, state]),
                                    episode_start=np.array([False, True]))
    going_on = agent.predict(going_obs, info, state=state)
    fresh = agent.predict(fresh_obs, info)
    np.testing.assert_allclose(actions, np.stack([going_on[0], fresh[0]]), atol=1e-5)
    np.testing.assert_array_equal(states, np.stack([going_on[1], fresh[1]]))
    return going_on, fresh


def test_predict_carries_the_gear_state_row_by_row():
    """An agent with the gear features (the committed policy alone): a batch's state is its
    rows' states, a row flagged by episode_start starts afresh, and a state of another shape
    is refused by name."""
    agent = load_agent(str(CHECKPOINTS[0]))
    assert "gear" in agent.config.agent.features
    env = agent.gym_env(seed=0)
    obs, info = env.reset()
    state = None
    for _ in range(3):  # a few steps in, so the car has a gear and a travel
        action, state = agent.predict(obs, info, state=state)
        obs, _r, _t, _u, info = env.step(action)
    moving = obs.copy()
    moving[4] = 1.5  # the row's speed after one more step: it drives on in its gear
    going_on, fresh = rows_predict_as_alone(agent, obs, moving, info, state)
    gear, travel = gear_travel(torch.tensor(obs[4]), torch.tensor(state[0]),
                               torch.tensor(state[1]), agent.config.env.task.vehicle.dt)
    assert tuple(going_on[1][:2]) == (gear.item(), travel.item())
    assert tuple(fresh[1][:2]) == (0.0, 2.0)  # a new episode: no gear, the full travel
    with pytest.raises(ValueError, match="state must be"):
        agent.predict(obs, info, state=np.zeros(3))
    with pytest.raises(ValueError, match="episode_start must"):
        agent.predict(np.stack([obs, moving]), {"position": np.stack([info["position"]] * 2)},
                      state=np.stack([state, state]), episode_start=np.array([True]))


def test_load_agent_names_a_file_that_is_not_a_checkpoint(tmp_path):
    bad = tmp_path / "model.pt"
    torch.save({"weights": torch.zeros(1)}, bad)
    with pytest.raises(ValueError, match=r"model\.pt"):
        load_agent(str(bad))


@pytest.mark.parametrize(("entry", "value", "message"), [
    ("obs_norm", "abc", r"its obs_norm must be a dict"),
    ("obs_norm", {}, r"its obs_norm does not fit the input normaliser"),
    ("frames", None, r"its frames must be an int >= 0"),
    ("frames", "many", r"its frames must be an int >= 0"),
    ("trained_by", 3, r"its trained_by must be a str"),
])
def test_a_crafted_checkpoint_entry_is_named_with_its_file(tmp_path, entry, value, message):
    saved = torch.load(CHECKPOINTS[0], weights_only=True)
    crafted = tmp_path / "crafted.pt"
    torch.save({**saved, entry: value}, crafted)
    with pytest.raises(ValueError, match=rf"checkpoint '.*crafted\.pt': {message}"):
        load_agent(str(crafted))
    with pytest.raises(ValueError, match=rf"crafted\.pt'?: {message}"):
        checkpoint_agent(str(crafted))
