"""Planner-guided pretraining: DAgger (Ross, Gordon and Bagnell 2011) on stable-baselines3's
public API, before RL fine-tunes the learner (a config's `pretrain:` section, PretrainParams).

pretrain() runs it; its docstring is the algorithm and why it is right. The labels are
played by farm.alloc.training.dagger.labels, on Ray by farm.alloc.training.dagger.tasks.
"""

from __future__ import annotations

import time

import numpy as np

from farm.alloc.allocators import Spec, allocator_entry
from farm.alloc.training.dagger.iterations import (
    iteration_file,
    latest_iteration,
    resume_iteration,
    run_digest,
    saved_iterations,
    write_iteration,
)
from farm.alloc.training.dagger.labels import concat, play_labelled

__all__ = ["PRETRAIN_SEED_OFFSET", "FLOW_FLOOR", "MoveMap", "imitation_loss", "label_all", "fit_actor", "fit_maps",
           "actor_action", "pretrain",
           "iteration_file", "saved_iterations", "latest_iteration", "Pretrained"]

PRETRAIN_SEED_OFFSET = 2_000_000  # pretraining's episodes: seeded apart from training's and evaluation's
FLOW_FLOOR = 0.01  # the weight of a cell without defenders in the `flows` loss


def label_all(config, params, learner, share: float, iteration: int, seed: int, client, gamma: float,
              progress=None) -> dict[str, np.ndarray]:
    """One iteration's episodes (play_labelled), in tasks of params.episodes_per_task: Ray tasks
    on the farm when client answers from the service actor (its backend has an `actor`),
    else in this process; results in task order. params: PretrainParams; seed: the run's."""
    spec = Spec(allocator_entry(params.expert, "pretrain.expert"), dict(params.expert_options))
    first = PRETRAIN_SEED_OFFSET + seed * 100_003 + iteration * params.episodes
    seeds = list(range(first, first + params.episodes))
    tasks = [(k, seeds[s: s + params.episodes_per_task])
             for k, s in enumerate(range(0, len(seeds), params.episodes_per_task))]

    coin_key = [seed, iteration, PRETRAIN_SEED_OFFSET]

    actor = getattr(client.backend, "actor", None)
    results: dict[int, dict] = {}
    if actor is None or _inside_ray_actor():
        expert = spec.make(config, client)
        for k, task_seeds in tasks:
            results[k] = play_labelled(config, expert, learner, share, task_seeds, coin_key, client, gamma)
            if progress is not None:
                progress(len(task_seeds), len(results[k]["obs"]))
    else:
        import ray

        from farm.alloc.training.dagger.tasks import remote_label
        from farm.runtime import bounded

        learner_ref = ray.put(learner)  # once, not once per task

        def submit(task):
            k, task_seeds = task
            return remote_label.remote(config, spec, learner_ref, share, task_seeds, coin_key, actor, gamma)

        cpus = max(1, int(ray.cluster_resources().get("CPU", 1)))  # the labelling keeps every CPU busy
        for (k, task_seeds), ref in bounded(submit, tasks, cpus):
            results[k] = ray.get(ref)
            if progress is not None:
                progress(len(task_seeds), len(results[k]["obs"]))
    return concat([results[k] for k, _ in tasks])


def _inside_ray_actor() -> bool:
    """Whether this runs in a Ray actor (an experiment's Tune trial): it holds its CPU while it
    waits, so tasks of its own could wait for CPUs the trials hold; it labels in its process."""
    import ray

    return ray.is_initialized() and ray.get_runtime_context().get_actor_id() is not None


def actor_action(model, algo: str, obs):
    """The learner's deterministic action of a batch of observations, differentiable: TD3's
    actor, SAC's deterministic (squashed) action, PPO's mean action. obs: (S, 2 N^2) float32
    tensor -> (S, A) tensor."""
    if algo == "td3":
        return model.actor(obs)
    if algo == "sac":
        return model.actor(obs, deterministic=True)
    return model.policy.get_distribution(obs).mode()


class MoveMap:
    """The env's map from an action to move probabilities (SwarmAllocationEnv.move_probabilities),
    in torch for a batch: config: the AllocConfig (its grid_size, action_map, softmax_beta)."""

    def __init__(self, config):
        import torch

        from farm.alloc.game.dynamics import moves

        src, _, _ = moves(config.grid_size)
        self.src = torch.as_tensor(src)
        self.cells = config.grid_size ** 2
        self.softmax = config.action_map == "softmax"
        self.softmax_beta = float(config.softmax_beta)

    def log_probabilities(self, action):
        """action: (S, A) tensor (clipped to [-1, 1], as the env does) -> (S, A) the log of each
        move's probability within its cell."""
        import torch

        a = action.clamp(-1.0, 1.0)
        index = self.src.expand(a.shape[0], -1)
        if self.softmax:
            z = self.softmax_beta * a
            top = torch.full((a.shape[0], self.cells), -torch.inf, dtype=a.dtype).scatter_reduce(1, index, z,
                                                                                                  reduce="amax")
            z = z - top.gather(1, index)
            total = torch.zeros(a.shape[0], self.cells, dtype=a.dtype).scatter_add(1, index, torch.exp(z))
            return z - torch.log(total.gather(1, index))
        w = a + 1.0 + 1e-6  # `shifted`; the env's uniform row for all -1 is this one's limit
        total = torch.zeros(a.shape[0], self.cells, dtype=a.dtype).scatter_add(1, index, w)
        return torch.log(w) - torch.log(total.gather(1, index))


def imitation_loss(kind: str, moves: MoveMap, action, labels, obs):
    """The pretraining loss of a batch (pretrain's doc): `actions`, mean squared error of action
    to labels; `flows`, the density-weighted cross-entropy of the move probabilities. action,
    labels: (S, A) tensors; obs: (S, 2 N^2) the observations (their first N^2 entries, the
    defenders' density, weigh the cells)."""
    import torch

    if kind == "actions":
        return torch.nn.functional.mse_loss(action, labels)
    with torch.no_grad():
        target = torch.exp(moves.log_probabilities(labels))
        weight = (obs[:, : moves.cells] + FLOW_FLOOR).gather(1, moves.src.expand(obs.shape[0], -1))
    return -(weight * target * moves.log_probabilities(action)).sum(dim=1).mean()


def fit_actor(model, algo: str, data: dict[str, np.ndarray], epochs: int, batch_size: int, learning_rate: float,
              rng: np.random.Generator, loss: str = "actions", env_config=None) -> float:
    """Fit the learner's actor (actor_action) to data's labels with Adam, epochs passes over data
    in minibatches drawn from rng, by imitation_loss `loss` (`flows` needs env_config, the
    AllocConfig); PPO: its value function to data's returns too. Returns the last epoch's
    mean imitation loss."""
    import torch

    moves = MoveMap(env_config) if loss == "flows" else None
    obs = torch.as_tensor(data["obs"])
    labels = torch.as_tensor(data["labels"])
    returns = torch.as_tensor(data["returns"], dtype=torch.float32)
    params = list(model.actor.parameters()) if algo in ("td3", "sac") else list(model.policy.parameters())
    optimizer = torch.optim.Adam(params, lr=learning_rate)
    model.policy.set_training_mode(True)
    last = float("nan")
    for _ in range(epochs):
        order = rng.permutation(len(obs))
        total = 0.0
        for start in range(0, len(order), batch_size):
            idx = torch.as_tensor(order[start: start + batch_size])
            error = imitation_loss(loss, moves, actor_action(model, algo, obs[idx]), labels[idx], obs[idx])
            total_loss = error
            if algo == "ppo":
                total_loss = total_loss + torch.nn.functional.mse_loss(model.policy.predict_values(obs[idx]).flatten(),
                                                                       returns[idx])
            optimizer.zero_grad()
            total_loss.backward()
            optimizer.step()
            total += float(error.detach()) * len(idx)
        last = total / len(order)
    model.policy.set_training_mode(False)
    if algo == "td3":
        model.actor_target.load_state_dict(model.actor.state_dict())
    return last


def fit_maps(model, datasets: list, epochs: int, batch_size: int, learning_rate: float, rng: np.random.Generator,
             loss: str = "flows") -> float:
    """fit_actor over several maps' labels for a CellPolicy PPO model: datasets, [(data, the map's
    AllocConfig)]; each epoch's minibatches hold one map's states each, their order drawn from
    rng; the network is switched to each minibatch's map (CellNet.use) and back to its own.
    Returns the last epoch's mean imitation loss."""
    import torch

    policy = model.policy
    net = policy.mlp_extractor
    own = (net.n, net.geometry.teams)
    maps = [(MoveMap(env), env, torch.as_tensor(d["obs"]), torch.as_tensor(d["labels"]),
             torch.as_tensor(d["returns"], dtype=torch.float32)) for d, env in datasets]
    optimizer = torch.optim.Adam(policy.parameters(), lr=learning_rate)
    policy.set_training_mode(True)
    last = float("nan")
    try:
        for _ in range(epochs):
            batches = []
            for j, (_, _, obs, _, _) in enumerate(maps):
                order = rng.permutation(len(obs))
                batches += [(j, order[start: start + batch_size]) for start in range(0, len(order), batch_size)]
            total, count = 0.0, 0
            for b in rng.permutation(len(batches)):
                j, rows = batches[b]
                moves, env, obs, labels, returns = maps[j]
                idx = torch.as_tensor(rows)
                net.use(env.grid_size, (env.n_defenders, env.n_intruders))
                action = net.forward_actor(obs[idx])  # CellPolicy's action net is the identity: the mean action
                error = imitation_loss(loss, moves, action, labels[idx], obs[idx])
                values = policy.value_net(net.forward_critic(obs[idx])).flatten()
                optimizer.zero_grad()
                (error + torch.nn.functional.mse_loss(values, returns[idx])).backward()
                optimizer.step()
                total += float(error.detach()) * len(idx)
                count += len(idx)
            last = total / count
    finally:
        net.use(*own)
        policy.set_training_mode(False)
    return last


def _maps(config, client) -> list[tuple]:
    """[(AllocConfig, client)]: the maps pretraining plays, the run's own first, then pretrain.maps'
    scenarios (the run's service games and seed), each with a client of its service settings."""
    maps = [(config.env, client)]
    for env in config.envs()[1:]:
        settings = env.game_settings()
        maps.append((env, client if settings == client.settings else client.with_settings(settings)))
    return maps


class Pretrained:
    """What pretraining did: states (labelled), seconds (wall), loss (the last fit's mean action
    error), data (the aggregated data set, play_labelled's arrays), resumed_after (the saved
    iteration it went on after, None: it began at the first)."""

    def __init__(self, states: int, seconds: float, loss: float, data: dict, resumed_after: int | None = None):
        self.states, self.seconds, self.loss, self.data = states, seconds, loss, data
        self.resumed_after = resumed_after


def pretrain(model, config, client, run_dir, *, show_progress: bool = True, on_progress=None) -> Pretrained:
    """DAgger on a new model of config (a TrainConfig with `pretrain:`), its
    episodes answered by client, resuming from run_dir's last saved iteration when there is one;
    then the replay buffer of an off-policy model is filled with the visited transitions.
    on_progress(episodes, total, saved): called with the episodes labelled so far (a resumed
    run's saved iterations counted) once a map's episodes of an iteration are labelled (saved
    None), and once an iteration is fitted and saved in run_dir (saved: the iteration); farm
    experiments reports a trial's pretraining to Tune so, with a Tune checkpoint of each saved
    iteration (farm.studies.experiments.tune.PretrainReport).

    The algorithm, and why it is right:

    - Iteration i plays `episodes` episodes with a mixture policy: at each step the expert drives
      with probability s_i (`expert_share`'s schedule, s_0 = 1: the first iteration is the expert's
      alone), else the learner (its deterministic action). Every visited state is labelled with
      the expert's action, whoever drove: the learner is taught what to do in the states its own
      mistakes lead to, which is what plain behaviour cloning misses (its errors compound over the
      episode; DAgger's do not).
    - The labels are the expert's predict() on the state's observation, exactly the action the
      expert would take there (the planners read only the observation), so a label is a pure
      function of the observation and the expert's settings.
    - After each iteration the learner's actor is fitted with Adam to every label gathered so
      far (the aggregated data set): TD3's and SAC's actor (SAC's deterministic, squashed
      action) and PPO's mean action (its distribution's mode), PPO's value function to the
      episodes' discounted returns beside it. The loss (`loss`) is either the mean squared error
      to the expert's action vector (`actions`) or, by default, what the action does (`flows`):
      the env turns each cell's slice of the action into the probabilities of its moves (the
      `action_map`) and only the cells holding defenders move anything, so the loss is the
      cross-entropy from the expert's move probabilities to the learner's, each cell weighted by
      its defenders' density (plus FLOW_FLOOR, so that empty cells are learnt a little too).
      Mean squared error spends the network on the action components of empty cells, which
      change nothing, and treats a small error in a cell holding all the defenders as small.
      TD3's target actor is set to the fitted actor. After the last iteration the visited
      transitions enter an off-policy learner's replay buffer, so that its critics start from
      the expert's kind of play.
    - Labels cost the expert's time a step (a planner's: docs/results.md), so episodes are
      played in tasks of `episodes_per_task` each: on the farm (service.mode ray) each task is
      one Ray task (farm.alloc.training.dagger.tasks) and at most one per CPU of the cluster
      runs at once; locally, and in an experiment's trial (a Ray actor that holds its CPU, so
      that tasks of its own could wait for CPUs the trials hold), they run one after another in
      this process. An episode and its coin flips are seeded by the run's seed, the iteration
      and the episode's index alone, and results are put together in task order, so the data set
      is the same whatever the number of workers.
    - A curriculum of maps (`maps`, for CellPolicy, whose weights fit any map): each iteration
      plays its episodes on the run's own map and on each named scenario (the learner driving
      there through its weights moved to that map, cell_policy.resized), and the fit goes over
      all the maps' labels, minibatches of one map each, in an order drawn from the fit's
      generator (fit_maps), so the one network learns what the expert does on every map.
    - Exact resume: after each iteration the data set, the learner's parameters and the fit's
      generator are written whole (pretrain/iteration_<i>.pkl, atomically, with the iteration,
      the run's digest and a checksum: farm.alloc.training.dagger.iterations). A run resumed
      after a stop loads the last one and goes on; nothing else is random (the fit draws its
      minibatches from its own generator, the networks have no dropout), so the pretrained
      policy is bit-identical to an uninterrupted run's. A last one that is not that
      iteration's whole state for this run (damaged, failing its checksum, stale, another
      run's, without a checksum) is moved to pretrain/damaged/, said in one line, and the one
      before goes on (or, with none, the pretraining starts again), as exact.
    """
    import torch

    from farm.core.progress import GameProgress

    params, algo = config.pretrain, config.algo
    gamma = config.learner.gamma
    schedule = params.schedule()
    maps = _maps(config, client)
    rng = np.random.default_rng([config.seed, PRETRAIN_SEED_OFFSET])
    parts: list[list[dict]] = [[] for _ in maps]  # each map's labels
    seconds, loss, first = 0.0, float("nan"), 0
    digest = run_digest(config)
    saved = resume_iteration(run_dir, digest, params.iterations, model.policy.state_dict(), len(maps))
    if saved is not None:
        done, state = saved
        parts = [[d] for d in (state["data"] if len(maps) > 1 else [state["data"]])]
        seconds, loss = state["seconds"], state["loss"]
        model.policy.load_state_dict(state["policy"])
        rng.bit_generator.state = state["rng"]
        first = done + 1
    total = params.iterations * params.episodes * len(maps)
    bar = GameProgress(total, first * params.episodes * len(maps), enabled=show_progress, desc="pretrain episodes",
                       unit="episode")
    tell = on_progress or (lambda episodes, total, saved: None)
    try:
        for iteration in range(first, params.iterations):
            t0 = time.perf_counter()
            for j, (env, env_client) in enumerate(maps):
                learner = None if schedule[iteration] >= 1 else _learner_on(model.policy, env, j)
                parts[j] = [concat(parts[j] + [label_all(env, params, learner, schedule[iteration], iteration,
                                                         config.seed, env_client, gamma,
                                                         progress=lambda episodes, states: bar.update(episodes))])]
                tell((iteration * len(maps) + j + 1) * params.episodes, total, None)
            if len(maps) == 1:
                loss = fit_actor(model, algo, parts[0][0], params.epochs, params.batch_size, params.learning_rate,
                                 rng, params.loss, config.env)
            else:
                loss = fit_maps(model, [(parts[j][0], env) for j, (env, _) in enumerate(maps)], params.epochs,
                                params.batch_size, params.learning_rate, rng, params.loss)
            seconds += time.perf_counter() - t0
            data = parts[0][0] if len(maps) == 1 else [p[0] for p in parts]
            state = {"iteration": iteration, "data": data, "policy": model.policy.state_dict(),
                     "rng": rng.bit_generator.state, "seconds": seconds, "loss": loss}
            write_iteration(run_dir, state, digest)
            tell((iteration + 1) * len(maps) * params.episodes, total, iteration)
    finally:
        bar.close()
    states = sum(len(p[0]["obs"]) for p in parts)  # labelled on every map
    data = parts[0][0]  # the run's own map's labels: the replay buffer's

    if algo == "td3":  # a resumed run's fresh model: its target actor as the fitted actor
        with torch.no_grad():
            model.actor_target.load_state_dict(model.actor.state_dict())
    if hasattr(model, "replay_buffer") and model.replay_buffer is not None:
        _fill_replay_buffer(model, data)
    return Pretrained(states, seconds, loss, data, None if saved is None else saved[0])


def _learner_on(policy, env, j: int):
    """The learner driving on map j: its own policy on its own map (j = 0), else its weights
    moved to env's map (cell_policy.resized)."""
    if j == 0:
        return policy
    from farm.alloc.networks.cell_policy import resized

    return resized(policy, env)


def _fill_replay_buffer(model, data: dict) -> None:
    """Add the visited transitions to an off-policy model's replay buffer, n_envs at a time (SB3's
    ReplayBuffer.add; a last group smaller than n_envs is left out)."""
    n = model.n_envs
    for start in range(0, len(data["obs"]) - n + 1, n):
        s = slice(start, start + n)
        done = data["terminated"][s] | data["truncated"][s]
        infos = [{"TimeLimit.truncated": bool(tr and not te)}
                 for te, tr in zip(data["terminated"][s], data["truncated"][s])]
        model.replay_buffer.add(data["obs"][s], data["next_obs"][s], data["actions"][s], data["rewards"][s], done,
                                infos)
