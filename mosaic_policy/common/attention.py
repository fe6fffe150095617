"""Sinusoidal spatio-temporal encodings and multi-head non-local attention over demo and observation frames.

Features are 5-D, (B, C, frames, h, w); queries, keys and values are 1x1x1 Conv3d projections.

MOSAIC pattern: demo tokens self-attend across all demo frames; each observation frame attends to its own
tokens and to the demo tokens, never to other observation frames. Every observation frame therefore gets the
same temporal code ("the current frame") and its output does not depend on how many observation frames are
in the batch: 7 frames in training and 1 at inference compute the same thing per frame (the original code's
encodings differed between the two). The demo stream is updated by every layer and its keys/values at each
layer depend on the demo only, so they can be computed once per episode and cached.

The observation stream is computed in one of two ways with the same output. Without attention maps (training, and
acting unless an episode's attention is recorded) it is one fused `scaled_dot_product_attention` call: frames are
folded into the batch and each frame's keys/values are [its own tokens, the demo tokens], so the kernel computes
exactly the pattern's query-key pairs, needs no mask and never forms the score matrix. With maps
(`return_weights=True`) it is computed explicitly in two score blocks, own and demo, under one softmax.

Full pattern (T-OSIL, and MOSAIC's attention ablation): the demo stream is the same, and observation frame t also
attends to the tokens of observation frames 0..t of its sample (causal: a frame never sees a later one). Acting,
the policy keeps the trunk features of its last frames and recomputes the observation stream over them; the demo
keys/values are cached as above.
"""

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn


def sinusoidal_table(positions: Tensor, dim: int) -> Tensor:
    """(len(positions), dim) sin/cos table, frequencies from 1 to 1/10000 as in the Transformer."""
    half = dim // 2
    freqs = torch.exp(-math.log(10000.0) * torch.arange(half, dtype=torch.float32) / max(half, 1))
    angles = positions.float()[:, None] * freqs[None, :]
    return torch.cat([angles.sin(), angles.cos()], dim=1)


def spatio_temporal_encoding(channels: int, time_indices: list[int], height: int, width: int) -> Tensor:
    """(channels, len(time_indices), height, width): a third of the channels each for time, row and column."""
    part = 2 * (channels // 6)
    t = sinusoidal_table(torch.tensor(time_indices), part)  # (T, part)
    y = sinusoidal_table(torch.arange(height), part)  # (h, part)
    x = sinusoidal_table(torch.arange(width), part)  # (w, part)
    n_t = len(time_indices)
    enc = torch.zeros(channels, n_t, height, width)
    enc[:part] = t.T[:, :, None, None].expand(part, n_t, height, width)
    enc[part : 2 * part] = y.T[:, None, :, None].expand(part, n_t, height, width)
    enc[2 * part : 3 * part] = x.T[:, None, None, :].expand(part, n_t, height, width)
    return enc


class NonLocalAttentionLayer(nn.Module):
    """One multi-head non-local block: attention with 1x1x1 Conv3d projections, residual, norm, 1x1x1 FFN."""

    def __init__(self, channels: int, n_heads: int, temperature: float, dropout: float = 0.0):
        super().__init__()
        if channels % n_heads:
            raise ValueError(f"channels ({channels}) must be divisible by n_attention_heads ({n_heads}).")
        self.n_heads = n_heads
        self.temperature = temperature
        self.query = nn.Conv3d(channels, channels, 1)
        self.key = nn.Conv3d(channels, channels, 1)
        self.value = nn.Conv3d(channels, channels, 1)
        self.out = nn.Conv3d(channels, channels, 1)
        self.norm_attention = nn.LayerNorm(channels)
        self.ffn = nn.Sequential(nn.Conv3d(channels, 2 * channels, 1), nn.ReLU(), nn.Conv3d(2 * channels, channels, 1))
        self.norm_ffn = nn.LayerNorm(channels)
        self.dropout = nn.Dropout(dropout)

    # The 1x1x1 Conv3d modules are applied as pointwise linear maps on channel-last tokens: the same
    # function and parameters, without the Conv3d kernel's overhead for tiny spatial sizes on CPU.
    @staticmethod
    def _pointwise(conv: nn.Conv3d, x: Tensor) -> Tensor:
        """(..., C_in) channel-last -> (..., C_out)."""
        return F.linear(x, conv.weight.flatten(1), conv.bias)

    def _heads(self, x: Tensor) -> Tensor:
        """(B, T, h, w, C) -> (B, heads, T, h*w, C/heads)."""
        b, t, h, w, c = x.shape
        return x.reshape(b, t, h * w, self.n_heads, c // self.n_heads).permute(0, 3, 1, 2, 4)

    @staticmethod
    def _merge(x: Tensor, like: Tensor) -> Tensor:
        """(B, heads, T, h*w, C/heads) -> (B, T, h, w, C) shaped like `like`."""
        return x.permute(0, 2, 3, 1, 4).reshape(like.shape)

    def _attend(self, q: Tensor, k: Tensor, v: Tensor, return_weights: bool) -> tuple[Tensor, Tensor | None]:
        if not return_weights:
            return F.scaled_dot_product_attention(q, k, v, scale=1.0 / self.temperature), None
        weights = torch.softmax(q @ k.transpose(-1, -2) / self.temperature, dim=-1)
        return weights @ v, weights

    def _residual(self, x: Tensor, attended: Tensor) -> Tensor:
        """Channel-last in and out: norm(x + out(attended)), then norm(x + ffn(x))."""
        x = self.norm_attention(x + self.dropout(self._pointwise(self.out, attended)))
        hidden = F.relu(self._pointwise(self.ffn[0], x))
        return self.norm_ffn(x + self.dropout(self._pointwise(self.ffn[2], hidden)))

    def _qkv(self, x: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        return tuple(self._heads(self._pointwise(proj, x)) for proj in (self.query, self.key, self.value))

    def demo_keys_values(self, demo: Tensor) -> tuple[Tensor, Tensor]:
        """Keys and values of all demo tokens (demo: (B, C, D, h, w)), (B, heads, D*h*w, C/heads) each."""
        x = demo.movedim(1, -1)
        k, v = (self._heads(self._pointwise(proj, x)).flatten(2, 3) for proj in (self.key, self.value))
        return k, v

    def forward_demo(self, demo: Tensor, demo_k: Tensor, demo_v: Tensor) -> Tensor:
        """Demo frames self-attend over all demo tokens (spatio-temporal)."""
        x = demo.movedim(1, -1)
        q = self._heads(self._pointwise(self.query, x))
        b, n_h, d, hw, dh = q.shape
        attended, _ = self._attend(q.flatten(2, 3), demo_k, demo_v, return_weights=False)
        return self._residual(x, self._merge(attended.reshape(b, n_h, d, hw, dh), x)).movedim(-1, 1)

    def forward_obs(
        self, obs: Tensor, demo_k: Tensor, demo_v: Tensor, return_weights: bool = False
    ) -> tuple[Tensor, Tensor | None]:
        """Each observation frame attends to [its own tokens, all demo tokens]; weights (B, heads, T, hw, hw + D*hw).

        One softmax over both key sets. Without `return_weights` (training, and acting without recording attention)
        this is one fused `scaled_dot_product_attention` call (`_obs_attention_fused`); the attention maps come from
        the explicit two-block computation (`_obs_attention_explicit`), which gives the same output.
        """
        x = obs.movedim(1, -1)
        if return_weights:
            attended, weights = self._obs_attention_explicit(x, demo_k, demo_v)
        else:
            attended, weights = self._obs_attention_fused(x, demo_k, demo_v), None
        return self._residual(x, attended).movedim(-1, 1), weights

    def _obs_attention_fused(self, x: Tensor, demo_k: Tensor, demo_v: Tensor) -> Tensor:
        """Channel-last x (B, T, h, w, C) -> attended (B, T, h, w, C), through one fused attention kernel.

        Frames are folded into the batch: each of the B*T frames is one attention problem whose keys/values are
        [its own h*w tokens, the sample's D*h*w demo tokens], so no mask is needed and no query-key pair outside
        the pattern is computed (a masked kernel computes the masked pairs too). The price is a copy of the demo
        keys/values per frame, about the size of the score matrix (B, heads, T, hw, hw + D*hw) that the explicit
        path materialises and keeps for its backward, and that the kernel never forms. At the paper's sizes on one
        CPU thread the attention itself (forward + backward) takes 0.65-0.85x the explicit computation's time; the
        whole layer stack about 0.9x, as the projections and FFN cost the same in both
        (pipelines/bench/policy_train_step.py). Tensors stay token-major, (frames, tokens, heads, C/heads) in
        memory, the layout the CPU kernel reads, so no head split or merge copies them.
        """
        b, t, h, w, c = x.shape
        n_h, hw = self.n_heads, h * w

        def tokens(proj: nn.Conv3d) -> Tensor:  # (B, T, hw, heads, C/heads), contiguous
            return self._pointwise(proj, x).reshape(b, t, hw, n_h, c // n_h)

        def with_demo(own: Tensor, demo: Tensor) -> Tensor:  # -> (B*T, heads, hw + D*hw, C/heads)
            demo = demo.transpose(1, 2).unsqueeze(1).expand(b, t, -1, -1, -1)  # views until the cat
            return torch.cat([own, demo], dim=2).flatten(0, 1).transpose(1, 2)

        q = tokens(self.query).flatten(0, 1).transpose(1, 2)  # (B*T, heads, hw, C/heads)
        keys, values = with_demo(tokens(self.key), demo_k), with_demo(tokens(self.value), demo_v)
        attended = F.scaled_dot_product_attention(q, keys, values, scale=1.0 / self.temperature)
        return attended.transpose(1, 2).reshape(x.shape)

    def _obs_attention_explicit(self, x: Tensor, demo_k: Tensor, demo_v: Tensor) -> tuple[Tensor, Tensor]:
        """The same attention with its weights (B, heads, T, hw, hw + D*hw): scores in two blocks (own, demo) so
        the demo keys are not copied per frame, one softmax over their concatenation."""
        q, k, v = self._qkv(x)
        b, n_h, t, hw, dh = q.shape
        q = q / self.temperature
        own_scores = q @ k.transpose(-1, -2)  # (B, heads, T, hw, hw)
        demo_scores = (q.flatten(2, 3) @ demo_k.transpose(-1, -2)).reshape(b, n_h, t, hw, -1)  # (..., D*hw)
        weights = torch.softmax(torch.cat([own_scores, demo_scores], dim=-1), dim=-1)
        own_w, demo_w = weights.split([hw, demo_scores.shape[-1]], dim=-1)
        attended = own_w @ v + (demo_w.flatten(2, 3) @ demo_v).reshape(b, n_h, t, hw, dh)
        return self._merge(attended, x), weights

    def forward_obs_causal(self, obs: Tensor, demo_k: Tensor, demo_v: Tensor) -> Tensor:
        """Full spatio-temporal pattern (T-OSIL): observation frame t attends to every demo token and to every
        token of observation frames 0..t, never to a later frame (training sees 7 frames, acting only the past)."""
        x = obs.movedim(1, -1)
        q, k, v = self._qkv(x)
        b, n_h, t, hw, dh = q.shape
        keys = torch.cat([demo_k, k.flatten(2, 3)], dim=2)
        values = torch.cat([demo_v, v.flatten(2, 3)], dim=2)
        query_frame = torch.arange(t, device=obs.device).repeat_interleave(hw)
        key_frame = torch.cat([torch.full((demo_k.shape[2],), -1, device=obs.device), query_frame])
        allowed = key_frame[None, :] <= query_frame[:, None]  # (T*hw, D*hw + T*hw)
        attended = F.scaled_dot_product_attention(
            q.flatten(2, 3), keys, values, attn_mask=allowed, scale=1.0 / self.temperature
        )
        return self._residual(x, self._merge(attended.reshape(b, n_h, t, hw, dh), x)).movedim(-1, 1)


class NonLocalAttentionStack(nn.Module):
    """Layers of non-local attention; `encode_demo` once per demonstration, `attend_obs` per observation."""

    def __init__(self, channels: int, n_layers: int, n_heads: int, temperature: float, dropout: float, pattern: str):
        super().__init__()
        self.pattern = pattern
        self.layers = nn.ModuleList(
            NonLocalAttentionLayer(channels, n_heads, temperature, dropout) for _ in range(n_layers)
        )

    @classmethod
    def from_config(cls, config, channels: int, pattern: str) -> "NonLocalAttentionStack":
        """The stack a policy config's attention options describe (layers, heads, temperature, dropout)."""
        return cls(channels, config.n_attention_layers, config.n_attention_heads, config.attention_temperature,
                   config.attention_dropout, pattern)

    def encode_demo(self, demo: Tensor) -> tuple[Tensor, list[tuple[Tensor, Tensor]]]:
        """Demo features through every layer; returns the output and each layer's demo keys/values (the cache)."""
        cache = []
        for layer in self.layers:
            k, v = layer.demo_keys_values(demo)
            cache.append((k, v))
            demo = layer.forward_demo(demo, k, v)
        return demo, cache

    def attend_obs(
        self, obs: Tensor, cache: list[tuple[Tensor, Tensor]], return_weights: bool = False
    ) -> tuple[Tensor, list[Tensor]]:
        weights = []
        for layer, (k, v) in zip(self.layers, cache, strict=True):
            obs, w = layer.forward_obs(obs, k, v, return_weights)
            if w is not None:
                weights.append(w)
        return obs, weights

    def attend_obs_causal(self, obs: Tensor, cache: list[tuple[Tensor, Tensor]]) -> Tensor:
        """The full (T-OSIL) pattern for observation frames (B, C, T, h, w), causal in time."""
        for layer, (k, v) in zip(self.layers, cache, strict=True):
            obs = layer.forward_obs_causal(obs, k, v)
        return obs

    def attend_observations(
        self, obs: Tensor, cache: list[tuple[Tensor, Tensor]], return_weights: bool = False
    ) -> tuple[Tensor, list[Tensor]]:
        """Observation frames (B, C, T, h, w) through every layer with this stack's pattern, given each layer's demo
        keys/values (from :meth:`encode_demo`, this demonstration's or another's); no weights with the full one."""
        if self.pattern == "full":
            return self.attend_obs_causal(obs, cache), []
        return self.attend_obs(obs, cache, return_weights)

    def forward(self, demo: Tensor, obs: Tensor, return_weights: bool = False) -> tuple[Tensor, Tensor, list[Tensor]]:
        demo_out, cache = self.encode_demo(demo)
        obs_out, weights = self.attend_observations(obs, cache, return_weights)
        return demo_out, obs_out, weights
