"""CellPolicy: PPO's actor-critic as one small network shared by every cell of the map.

The allocation action is, for each cell, a score for each of its feasible moves (stay or one of
its 8 neighbours: farm.alloc.dynamics.moves; the env turns a cell's scores into its move
probabilities). An MLP over the flat observation learns each cell's scores separately, with a
parameter count that grows with N^2, and must learn the same rule once per cell. CellPolicy
computes them the way they are defined, per cell:

- the observation (B, 2 N^2) float32, [D, I] in cell order, is read as a (B, 5, N, N) image:
  D, I, a channel of ones (so that the zero padding beyond the map's edge is seen as outside,
  unlike an empty cell inside it) and the cell's column and row, each scaled to [0, 1];
- `layers` 3 x 3 convolutions of `channels` channels, each followed by adding a linear map of
  the mean over the map of its output (every cell hears a summary of the whole map) and a ReLU;
- the actor: a 1 x 1 convolution to 9 scores per cell, one per move (d_row, d_col) in row-major
  order, of which each cell's feasible moves are gathered in the action vector's order; the
  moves off the map are never in the action, so no mask is needed;
- the critic: the same trunk (a second copy: the value's gradients do not move the actor's
  features) pooled by mean and max over the cells into the value head.

Its weights do not depend on N but for PPO's state-independent log_std, one per action entry
(SB3's DiagGaussianDistribution). It plugs into stable-baselines3 through the documented route
for custom networks, a policy class overriding `_build_mlp_extractor`: the extractor's
latent_dim_pi is the action's length, and the action net that SB3 puts after it is an identity
(the scores are the Gaussian's means), the optimizer built again over the parameters that
remain. config: `ppo: {policy: CellPolicy, policy_kwargs: {channels: 32, layers: 3}}`.
"""

from __future__ import annotations

import numpy as np
import torch
from stable_baselines3.common.policies import ActorCriticPolicy
from torch import nn

from farm.alloc.dynamics import moves

__all__ = ["CellPolicy", "CellNet"]


class _Trunk(nn.Module):
    """(B, 2 N^2) observations -> (B, channels, N, N) per-cell features (the module doc)."""

    def __init__(self, n: int, channels: int, layers: int):
        super().__init__()
        self.n = n
        self.convs = nn.ModuleList(nn.Conv2d(5 if i == 0 else channels, channels, 3, padding=1) for i in range(layers))
        self.mix = nn.ModuleList(nn.Linear(channels, channels) for _ in range(layers))
        axis = torch.linspace(0.0, 1.0, n) if n > 1 else torch.zeros(1)
        rows, cols = torch.meshgrid(axis, axis, indexing="ij")
        self.register_buffer("place", torch.stack([torch.ones(n, n), cols, rows])[None], persistent=False)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        n = self.n
        h = torch.cat([obs.reshape(-1, 2, n, n), self.place.expand(len(obs), -1, -1, -1)], dim=1)
        for conv, mix in zip(self.convs, self.mix):
            h = conv(h)
            h = torch.relu(h + mix(h.mean(dim=(2, 3)))[:, :, None, None])
        return h


class CellNet(nn.Module):
    """SB3's mlp_extractor for CellPolicy: forward_actor gives (B, A) move scores,
    forward_critic (B, 2 channels) pooled features, from (B, 2 N^2) float32 observations."""

    def __init__(self, n: int, channels: int, layers: int):
        super().__init__()
        src, dst, _ = moves(n)
        move = (dst // n - src // n + 1) * 3 + (dst % n - src % n + 1)  # (d_row, d_col) in row-major order
        self.register_buffer("index", torch.as_tensor(move * n * n + src), persistent=False)
        self.actor = _Trunk(n, channels, layers)
        self.scores = nn.Conv2d(channels, 9, 1)
        self.critic = _Trunk(n, channels, layers)
        self.latent_dim_pi = len(src)
        self.latent_dim_vf = 2 * channels

    def forward_actor(self, obs: torch.Tensor) -> torch.Tensor:
        """(B, 2 N^2) float32 observations -> (B, A) move scores in the action's order."""
        return self.scores(self.actor(obs)).flatten(1)[:, self.index]

    def forward_critic(self, obs: torch.Tensor) -> torch.Tensor:
        """(B, 2 N^2) float32 observations -> (B, 2 channels) the critic's features, mean and max over cells."""
        h = self.critic(obs)
        return torch.cat([h.mean(dim=(2, 3)), h.amax(dim=(2, 3))], dim=1)

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(forward_actor(obs), forward_critic(obs)), as SB3's extractors return them."""
        return self.forward_actor(obs), self.forward_critic(obs)


class CellPolicy(ActorCriticPolicy):
    """PPO's policy of per-cell shared weights (the module doc). channels: int >= 1, layers:
    int >= 1; the other arguments are ActorCriticPolicy's."""

    def __init__(self, observation_space, action_space, lr_schedule, channels: int = 32, layers: int = 3, **kwargs):
        self.grid = int(round(np.sqrt(observation_space.shape[0] / 2)))
        self.channels, self.layers = channels, layers
        super().__init__(observation_space, action_space, lr_schedule, **kwargs)
        self.action_net = nn.Identity()  # the scores are the means
        nn.init.orthogonal_(self.mlp_extractor.scores.weight, gain=0.01)  # as SB3 starts its action net
        nn.init.zeros_(self.mlp_extractor.scores.bias)
        self.optimizer = self.optimizer_class(self.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)

    def _build_mlp_extractor(self) -> None:
        self.mlp_extractor = CellNet(self.grid, self.channels, self.layers)
