"""Discretised logistic mixture over evenly spaced bins on [low, high] (one distribution per action dimension).

Bin k has centre low + k * width, width = (high - low) / (num_bins - 1); the first and last bins absorb the
tails, so the bin probabilities of a mixture sum to one. Values are snapped to the nearest bin centre.
"""

import torch
import torch.nn.functional as F
from torch import Tensor, nn

LOG_SCALE_MIN = -7.0


class DiscretizedLogisticMixture:
    """A batch of discretised logistic mixtures; parameters have shape (..., n_mixtures)."""

    def __init__(
        self,
        logit_probs: Tensor,
        means: Tensor,
        log_scales: Tensor,
        num_bins: int = 256,
        low: float = -1.0,
        high: float = 1.0,
    ):
        self.logit_probs = logit_probs
        self.means = means
        self.log_scales = log_scales.clamp(min=LOG_SCALE_MIN)
        self.num_bins = num_bins
        self.low = low
        self.high = high
        self.bin_width = (high - low) / (num_bins - 1)

    def snap(self, x: Tensor) -> Tensor:
        """Nearest bin centre of each value (values outside [low, high] go to the edge bins)."""
        k = torch.round((x.clamp(self.low, self.high) - self.low) / self.bin_width)
        return self.low + k * self.bin_width

    def log_prob(self, x: Tensor) -> Tensor:
        """Log probability of the bin holding each value of x (shape: parameters without the mixture axis)."""
        x = self.snap(x).unsqueeze(-1)
        half = self.bin_width / 2
        inv_scale = torch.exp(-self.log_scales)
        centered = x - self.means
        plus_in = inv_scale * (centered + half)
        minus_in = inv_scale * (centered - half)
        log_cdf_plus = F.logsigmoid(plus_in)  # log P(X < x + half): the first bin
        log_one_minus_cdf_minus = F.logsigmoid(-minus_in)  # log P(X > x - half): the last bin
        cdf_delta = torch.sigmoid(plus_in) - torch.sigmoid(minus_in)
        # Far in a tail cdf_delta underflows: use the density at the centre times the width there.
        mid_in = inv_scale * centered
        log_pdf_mid = mid_in - self.log_scales - 2.0 * F.softplus(mid_in)
        log_inner = torch.where(
            cdf_delta > 1e-5,
            torch.log(cdf_delta.clamp(min=1e-12)),
            log_pdf_mid + torch.log(torch.tensor(self.bin_width, dtype=x.dtype, device=x.device)),
        )
        # x sits on a bin centre: half a bin from the edges tells the edge bins apart in any float precision
        # (a relative epsilon of the width is below float32's resolution at +-1, and the tails went missing).
        log_bin = torch.where(
            x < self.low + half,
            log_cdf_plus,
            torch.where(x > self.high - half, log_one_minus_cdf_minus, log_inner),
        )
        return torch.logsumexp(log_bin + F.log_softmax(self.logit_probs, dim=-1), dim=-1)

    def sample(self, generator: torch.Generator | None = None) -> Tensor:
        """One bin centre per distribution: pick a component, draw a logistic value, snap it to a bin."""
        probs = F.softmax(self.logit_probs, dim=-1)
        flat = probs.reshape(-1, probs.shape[-1])
        component = torch.multinomial(flat, 1, generator=generator).reshape(probs.shape[:-1] + (1,))
        mean = self.means.gather(-1, component).squeeze(-1)
        log_scale = self.log_scales.gather(-1, component).squeeze(-1)
        u = torch.rand(mean.shape, generator=generator, dtype=mean.dtype, device=mean.device)
        u = u.clamp(1e-5, 1.0 - 1e-5)
        return self.snap(mean + torch.exp(log_scale) * (torch.log(u) - torch.log1p(-u)))

    def mode(self) -> Tensor:
        """Mean of the most probable component, snapped to a bin (deterministic action at inference)."""
        component = self.logit_probs.argmax(dim=-1, keepdim=True)
        return self.snap(self.means.gather(-1, component).squeeze(-1))


class DiscretizedLogisticHead(nn.Module):
    """MLP from an embedding to a discretised logistic mixture per action dimension."""

    def __init__(self, in_dim: int, action_dim: int, n_mixtures: int, hidden_dim: int, num_bins: int = 256):
        super().__init__()
        self.action_dim = action_dim
        self.n_mixtures = n_mixtures
        self.num_bins = num_bins
        self.mlp = nn.Sequential(
            nn.Linear(in_dim, hidden_dim),
            nn.ReLU(),
            nn.Linear(hidden_dim, hidden_dim),
            nn.ReLU(),
            nn.Linear(hidden_dim, action_dim * n_mixtures * 3),
        )

    def forward(self, x: Tensor) -> DiscretizedLogisticMixture:
        params = self.mlp(x).reshape(*x.shape[:-1], self.action_dim, 3, self.n_mixtures)
        logit_probs, means, log_scales = params.unbind(dim=-2)
        return DiscretizedLogisticMixture(logit_probs, means, log_scales, num_bins=self.num_bins)
