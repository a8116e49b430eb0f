"""CellPolicy: PPO's actor-critic as one small network shared by every cell of the map, of
any size.

CellPolicy's docstring says what it computes and why its weights fit any map; MapGeometry,
CellNet and resized are its parts.
"""

from __future__ import annotations

import numpy as np
import torch
from stable_baselines3.common.policies import ActorCriticPolicy
from torch import nn

from farm.alloc.game.dynamics import moves

__all__ = ["CellPolicy", "CellNet", "MapGeometry", "resized"]

COUNT_SCALE = float(np.log1p(256.0))  # the lattice's largest team, log1p-scaled to 1


class MapGeometry:
    """What CellPolicy's network needs to know of one map, none of it learnt: n, the grid side;
    teams, (n_defenders, n_intruders); place: (1, 3, n, n) float32 the ones, column and row
    channels; scale: (1, 2, 1, 1) float32 the teams; index: (A,) int64 each action entry's place in the
    flattened (9, n, n) move scores (the feasible moves, in moves(n)'s order)."""

    def __init__(self, n: int, teams: tuple[int, int]):
        self.n, self.teams = n, (int(teams[0]), int(teams[1]))
        axis = torch.linspace(0.0, 1.0, n) if n > 1 else torch.zeros(1)
        rows, cols = torch.meshgrid(axis, axis, indexing="ij")
        self.place = torch.stack([torch.ones(n, n), cols, rows])[None]
        self.scale = torch.tensor([float(teams[0]), float(teams[1])]).reshape(1, 2, 1, 1)
        src, dst, _ = moves(n)
        move = (dst // n - src // n + 1) * 3 + (dst % n - src % n + 1)  # (d_row, d_col) in row-major order
        self.index = torch.as_tensor(move * n * n + src)


def _maxima_before_after(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """x: (..., N) float32 -> (before, after), (..., N) float32 each: at k the maximum of x over
    the entries before k and over those after it; -1e4 ("nothing there") where there are none."""
    edge = torch.full_like(x[..., :1], -1e4)
    before = torch.cat([edge, torch.cummax(x, dim=-1).values[..., :-1]], dim=-1)
    after = torch.cat([torch.cummax(x.flip(-1), dim=-1).values.flip(-1)[..., 1:], edge], dim=-1)
    return before, after


def balance_shares(densities: torch.Tensor) -> torch.Tensor:
    """densities: (B, 2, N, N) float32 the defenders' and intruders' shares per cell -> (B, 4, N, N)
    float32, per cell: the defenders' share in the rows above the cell's and in the rows below
    it, then the intruders' share of the intruder mass on the map in those rows (0 on an empty
    map). Row 0 is the top: nothing is above it."""
    rows = densities.sum(dim=3)  # (B, 2, N)
    total = rows.sum(dim=2, keepdim=True)  # (B, 2, 1)
    above = torch.cumsum(rows, dim=2) - rows
    below = total - above - rows
    scale = torch.ones_like(total)
    scale[:, 1] = 1.0 / torch.clamp(total[:, 1], min=1e-6)  # intruders: shares of what is left
    n = densities.shape[3]
    shares = torch.stack([above * scale, below * scale], dim=2)  # (B, 2 teams, 2 sides, N)
    return torch.clamp(shares, 0.0, 1.0).reshape(-1, 4, shares.shape[3], 1).expand(-1, -1, -1, n)


class _Trunk(nn.Module):
    """(B, 2 N^2) observations of a map (its MapGeometry) -> (B, channels, N, N) per-cell
    features (CellPolicy's doc)."""

    def __init__(self, channels: int, layers: int, positions: bool = True, lateral: bool = False,
                 balance: bool = False):
        super().__init__()
        self.positions, self.lateral, self.balance = positions, lateral, balance
        inputs = (7 if positions else 5) + (4 if balance else 0)
        self.convs = nn.ModuleList(nn.Conv2d(inputs if i == 0 else channels, channels, 3, padding=1)
                                   for i in range(layers))
        self.row = nn.ModuleList(nn.Conv1d(channels, channels, 1) for _ in range(layers))
        self.above = nn.ModuleList(nn.Conv1d(channels, channels, 1, bias=False) for _ in range(layers))
        self.below = nn.ModuleList(nn.Conv1d(channels, channels, 1, bias=False) for _ in range(layers))
        self.top = nn.ModuleList(nn.Linear(channels, channels, bias=False) for _ in range(layers))
        if lateral:
            self.left = nn.ModuleList(nn.Conv2d(channels, channels, 1, bias=False) for _ in range(layers))
            self.right = nn.ModuleList(nn.Conv2d(channels, channels, 1, bias=False) for _ in range(layers))

    def forward(self, obs: torch.Tensor, geometry: MapGeometry) -> torch.Tensor:
        n = geometry.n
        counts = obs.reshape(-1, 2, n, n) * geometry.scale
        rows = counts.sum(dim=3, keepdim=True).expand(-1, -1, -1, n)
        place = geometry.place if self.positions else geometry.place[:, :1]
        channels = [torch.log1p(counts) / COUNT_SCALE, torch.log1p(rows) / COUNT_SCALE,
                    place.expand(len(obs), -1, -1, -1)]
        if self.balance:
            channels.append(balance_shares(obs.reshape(-1, 2, n, n)))
        h = torch.cat(channels, dim=1)
        for i, (conv, row, above, below, top) in enumerate(zip(self.convs, self.row, self.above, self.below, self.top)):
            h = conv(h)
            r = h.amax(dim=3)  # (B, C, N) each row's maximum
            before, after = _maxima_before_after(r)  # over the rows above, over the rows below
            summary = (row(r) + above(torch.relu(before)) + below(torch.relu(after)))[..., None]
            if self.lateral:
                left, right = _maxima_before_after(h)  # over the cells to the left in the row, to the right
                summary = summary + self.left[i](torch.relu(left)) + self.right[i](torch.relu(right))
            h = torch.relu(h + summary + top(h.amax(dim=(2, 3)))[:, :, None, None])
        return h


class CellNet(nn.Module):
    """SB3's mlp_extractor for CellPolicy: forward_actor gives (B, A) move scores,
    forward_critic (B, 2 channels) pooled features, from (B, 2 N^2) float32 observations of
    the map it is on (use(); first the map of n and teams). Its parameters fit any map."""

    def __init__(self, n: int, channels: int, layers: int, teams: tuple[int, int] = (1, 1), positions: bool = True,
                 lateral: bool = False, balance: bool = False):
        super().__init__()
        self.actor = _Trunk(channels, layers, positions, lateral, balance)
        self.scores = nn.Conv2d(channels, 9, 1)
        self.critic = _Trunk(channels, layers, positions, lateral, balance)
        self.latent_dim_vf = 2 * channels
        self._maps: dict[tuple, MapGeometry] = {}
        self.use(n, teams)
        self.latent_dim_pi = len(self.index)

    def use(self, n: int, teams: tuple[int, int]) -> CellNet:
        """Act on the map of grid side n and teams (n_defenders, n_intruders) from now on; returns self."""
        key = (int(n), int(teams[0]), int(teams[1]))
        if key not in self._maps:
            self._maps[key] = MapGeometry(n, teams)
        self.geometry = self._maps[key]
        self.n, self.index = self.geometry.n, self.geometry.index
        return self

    def forward_actor(self, obs: torch.Tensor) -> torch.Tensor:
        """(B, 2 N^2) float32 observations -> (B, A) move scores in the action's order."""
        return self.scores(self.actor(obs, self.geometry)).flatten(1)[:, self.index]

    def forward_critic(self, obs: torch.Tensor) -> torch.Tensor:
        """(B, 2 N^2) float32 observations -> (B, 2 channels) the critic's features, mean and max over cells."""
        h = self.critic(obs, self.geometry)
        return torch.cat([h.mean(dim=(2, 3)), h.amax(dim=(2, 3))], dim=1)

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(forward_actor(obs), forward_critic(obs)), as SB3's extractors return them."""
        return self.forward_actor(obs), self.forward_critic(obs)


class CellPolicy(ActorCriticPolicy):
    """PPO's policy of per-cell shared weights.

    The allocation action is, for each cell, a score for each of its feasible moves (stay or one of
    its 8 neighbours: farm.alloc.game.dynamics.moves; the env turns a cell's scores into its move
    probabilities). An MLP over the flat observation learns each cell's scores separately, with a
    parameter count that grows with N^2, and must learn the same rule once per cell. CellPolicy
    computes them the way they are defined, per cell, with weights that do not depend on N:

    - the observation (B, 2 N^2) float32, [D, I] in cell order, is read as a (B, 7, N, N) image of
      what is the same on any map: the cell's defenders and intruders as team counts (D_c
      n_defenders, I_c n_intruders, the engagement's own inputs) and its row's totals, each
      log1p-scaled by log1p(256) (the lattice's largest team); a channel of ones (so that the zero
      padding beyond the map's edge is seen as outside, unlike an empty cell inside it); the cell's
      column and row scaled to [0, 1], unless `positions` is false; with `balance`, four more: the
      shares of the intruder mass in the rows above the cell's and in the rows below it (of the mass
      left on the map) and the shares of the defenders there (the transport balance: a cell whose
      rows above hold more of the intruders than of the defenders sends defenders up, however far;
      shares, so the same on any map);
    - `layers` 3 x 3 convolutions of `channels` channels, each followed by adding linear maps of
      four summaries and a ReLU: the maximum over the cell's row (what its row holds, however far),
      the maximum over the rows above it and over the rows below it (where to send defenders, up or
      down, on a map of any height), and the maximum over the map. Maxima, not means: a mean over a
      row of N cells dilutes one cell's signal by N, so what a network learnt on an 8 x 8 map would
      read four times weaker on a 32 x 32 one; a maximum reads the same on any map. With `lateral`,
      two more: the maximum over the cells to the left of the cell in its row and over those to its
      right (where to send defenders along the row, however far: without them the three 3 x 3
      layers see 3 cells to each side, most of an 8 x 8 row but a tenth of a 32 x 32 one);
    - the actor: a 1 x 1 convolution to 9 scores per cell, one per move (d_row, d_col) in row-major
      order, of which each cell's feasible moves are gathered in the action vector's order: the
      moves off the map are masked by never being in the action;
    - the critic: the same trunk (a second copy: the value's gradients do not move the actor's
      features) pooled by mean and max over the cells into the value head.

    The teams' sizes (`teams`: n_defenders, n_intruders) are the env's, given by the trainer
    (farm.alloc.training.train.make_model), not learned. Every weight is the same tensor on any
    map but PPO's state-independent log_std, one per action entry (SB3's
    DiagGaussianDistribution), which only the exploration noise uses: resized() makes the policy
    for another map (another N, other teams) with the same weights and log_std at its mean, which
    `farm eval RUN --scenario NAME` evaluates deterministically. It plugs into stable-baselines3
    through the documented route for custom networks, a policy class overriding
    `_build_mlp_extractor`: the extractor's latent_dim_pi is the action's length, and the action
    net that SB3 puts after it is an identity (the scores are the Gaussian's means), the optimizer
    built again over the parameters that remain. config: `ppo: {policy: CellPolicy, policy_kwargs:
    {channels: 32, layers: 3}}`.

    channels: int >= 1, layers: int >= 1; teams: (n_defenders, n_intruders) of the env;
    positions, lateral, balance: the options above; the other arguments are
    ActorCriticPolicy's."""

    def __init__(self, observation_space, action_space, lr_schedule, channels: int = 32, layers: int = 3,
                 teams: tuple[int, int] = (1, 1), positions: bool = True, lateral: bool = False,
                 balance: bool = False, **kwargs):
        self.grid = int(round(np.sqrt(observation_space.shape[0] / 2)))
        self.channels, self.layers, self.teams = channels, layers, (int(teams[0]), int(teams[1]))
        self.positions, self.lateral, self.balance = positions, lateral, balance
        super().__init__(observation_space, action_space, lr_schedule, **kwargs)
        self.action_net = nn.Identity()  # the scores are the means
        nn.init.orthogonal_(self.mlp_extractor.scores.weight, gain=0.01)  # as SB3 starts its action net
        nn.init.zeros_(self.mlp_extractor.scores.bias)
        self.optimizer = self.optimizer_class(self.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)

    def _build_mlp_extractor(self) -> None:
        self.mlp_extractor = CellNet(self.grid, self.channels, self.layers, self.teams, self.positions, self.lateral,
                                    self.balance)


def resized(policy: CellPolicy, config) -> CellPolicy:
    """policy's weights as a CellPolicy for the map of config (an AllocConfig: its grid_size and
    teams), log_std at the mean of policy's (CellPolicy's doc); policy itself if it fits already.
    The result acts in evaluation mode, deterministic actions being the policy's means."""
    import gymnasium as gym

    from farm.alloc.game.dynamics import n_actions

    n = config.grid_size
    teams = (config.n_defenders, config.n_intruders)
    if policy.grid == n and policy.teams == teams:
        return policy
    obs_space = gym.spaces.Box(0.0, 1.0, shape=(2 * n * n,), dtype=np.float32)
    act_space = gym.spaces.Box(-1.0, 1.0, shape=(n_actions(n),), dtype=np.float32)
    # The other constructor arguments (initialisation, optimizer) are of no use to loaded weights:
    # no orthogonal initialisation, whose QR of SB3's (A, A) action net (replaced by the identity)
    # takes seconds on 32 x 32 (A = 8,836).
    other = CellPolicy(obs_space, act_space, lambda _: 0.0, channels=policy.channels, layers=policy.layers,
                       teams=teams, positions=policy.positions, lateral=policy.lateral,
                       balance=policy.balance,
                       ortho_init=False)
    state = policy.state_dict()
    state["log_std"] = torch.full((n_actions(n),), float(state["log_std"].mean()))
    other.load_state_dict(state)
    other.set_training_mode(False)
    return other
