"""PyTorch reference of the paper's network, timed on this machine (run by `benchmarks/train_sps.py --torch`).

The recurrent actor-critic of Ndousse et al. (2021), appendix "Network architecture details", written with
stock PyTorch layers, as the baseline that jaxsocial's learner (`jaxsocial.agents.network`) is compared with:

    obs float[3, 21, 21] -> Conv(3->32, 3x3, stride 3) -> Conv(32->64, 3x3) -> Conv(64->64, 3x3)
        (leaky ReLU after each; 21 -> 7 -> 5 -> 3, flattened to 576)
      -> Linear(576->192) -> tanh -> LSTM(192)                                          hidden h
    value  = MLP 192 -> 64 -> 64 -> 1 (tanh hidden layers)
    policy = MLP 192 -> 64 -> 64 -> 7 (tanh hidden layers)
    aux    = Linear(192 + 7 -> 576) on [h, one_hot(action)] -> tanh -> (64, 3, 3)
      -> ConvTranspose(64->64, 3x3) -> leaky ReLU -> ConvTranspose(64->32, 3x3) -> leaky ReLU
      -> ConvTranspose(32->3, 3x3, stride 3)                                            3 -> 5 -> 7 -> 21

668,555 parameters: jaxsocial's 667,787 plus 768 because `torch.nn.LSTM` keeps two bias vectors
(`bias_ih` and `bias_hh`, 4 x 192 each) where one suffices.

Measured: samples/s of a full gradient step (value, policy and auxiliary heads; loss
`mean(value^2) - mean(log_softmax(logits)) + mean(|decoded - obs|)`, the same as train_sps.py's JAX loss) and
of a forward pass without gradients, on one minibatch of `--batch` sequences x `--seq` steps of random
observations in [0, 1) (the scale of uint8 frames / 255). Each is called once untimed, then `--reps` times;
the rate is all timed samples over the total timed seconds. `--dtype bfloat16` runs the forward pass and the
loss under ``torch.autocast("cpu", torch.bfloat16)`` (bfloat16 convolutions, linear layers and LSTM,
float32 parameters and gradients; jaxsocial's ``--net.dtype bfloat16`` likewise). The last line printed is
one JSON object with `framework`, `threads`, `dtype`, `samples`, `params`, `grad_samples_per_s` and
`forward_samples_per_s`.

PyTorch is not a dependency of jaxsocial; this file is the only place that imports it. Give it its own
virtual environment, for example:

    python3 -m venv ~/torchref && ~/torchref/bin/pip install torch numpy
    ~/torchref/bin/python benchmarks/pytorch_paper_net.py --threads 2
    python benchmarks/train_sps.py --torch ~/torchref/bin/python      # side by side with jaxsocial
"""

from __future__ import annotations

import argparse
import json
import sys
import time

try:
    import torch
    from torch import nn
except ImportError:  # pragma: no cover - depends on the interpreter
    sys.exit("pytorch_paper_net.py needs PyTorch: run it with a Python that has torch installed")

OBS_SIDE = 21
N_ACTIONS = 7
HIDDEN = 192
MLP = 64
FEATURE_SHAPE = (64, 3, 3)
FEATURES = 64 * 3 * 3


def mlp_head(n_out: int) -> nn.Sequential:
    """HIDDEN -> MLP -> MLP -> n_out with tanh between the layers."""
    return nn.Sequential(
        nn.Linear(HIDDEN, MLP), nn.Tanh(), nn.Linear(MLP, MLP), nn.Tanh(), nn.Linear(MLP, n_out)
    )


class Encoder(nn.Module):
    """float[n, 3, 21, 21] frames -> float[n, HIDDEN] features (before the LSTM)."""

    def __init__(self):
        super().__init__()
        self.convs = nn.Sequential(
            nn.Conv2d(3, 32, kernel_size=3, stride=3),
            nn.LeakyReLU(),
            nn.Conv2d(32, 64, kernel_size=3),
            nn.LeakyReLU(),
            nn.Conv2d(64, 64, kernel_size=3),
            nn.LeakyReLU(),
            nn.Flatten(),
        )
        self.dense = nn.Linear(FEATURES, HIDDEN)

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        return torch.tanh(self.dense(self.convs(frames)))


class Decoder(nn.Module):
    """The auxiliary head: (float[n, HIDDEN] hidden state, int[n] action) -> float[n, 3, 21, 21] frame."""

    def __init__(self):
        super().__init__()
        self.dense = nn.Linear(HIDDEN + N_ACTIONS, FEATURES)
        self.deconvs = nn.Sequential(
            nn.ConvTranspose2d(64, 64, kernel_size=3),
            nn.LeakyReLU(),
            nn.ConvTranspose2d(64, 32, kernel_size=3),
            nn.LeakyReLU(),
            nn.ConvTranspose2d(32, 3, kernel_size=3, stride=3),
        )

    def forward(self, hidden: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        one_hot = nn.functional.one_hot(actions, N_ACTIONS).to(hidden.dtype)
        z = torch.tanh(self.dense(torch.cat([hidden, one_hot], dim=-1)))
        return self.deconvs(z.view(-1, *FEATURE_SHAPE))


class PaperNetwork(nn.Module):
    """Sequences in, per-step value, logits and decoded frame out (time-major, like `nn.LSTM`)."""

    def __init__(self):
        super().__init__()
        self.encoder = Encoder()
        self.lstm = nn.LSTM(HIDDEN, HIDDEN)
        self.value_head = mlp_head(1)
        self.policy_head = mlp_head(N_ACTIONS)
        self.decoder = Decoder()

    def forward(self, obs: torch.Tensor, actions: torch.Tensor):
        """obs float[T, B, 3, 21, 21], actions int64[T, B] -> value [T, B, 1], logits [T, B, 7],
        decoded frames [T, B, 3, 21, 21]. The LSTM starts from zeros."""
        steps, batch = obs.shape[:2]
        features = self.encoder(obs.flatten(0, 1)).view(steps, batch, HIDDEN)
        hidden, _ = self.lstm(features)
        decoded = self.decoder(hidden.flatten(0, 1), actions.flatten())
        return (
            self.value_head(hidden),
            self.policy_head(hidden),
            decoded.view(steps, batch, 3, OBS_SIDE, OBS_SIDE),
        )


def samples_per_second(step, samples: int, reps: int) -> float:
    """One untimed call of `step`, then `reps` timed calls: timed samples / timed seconds."""
    step()
    elapsed = 0.0
    for _ in range(reps):
        start = time.perf_counter()
        step()
        elapsed += time.perf_counter() - start
    return samples * reps / elapsed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--threads", type=int, default=2, help="torch.set_num_threads")
    parser.add_argument("--batch", type=int, default=512, help="sequences per minibatch (paper: 512)")
    parser.add_argument("--seq", type=int, default=16, help="steps per sequence (paper: 16)")
    parser.add_argument("--reps", type=int, default=3, help="timed calls of each kind")
    parser.add_argument("--dtype", choices=("float32", "bfloat16"), default="float32", help="compute dtype")
    args = parser.parse_args()
    compute = torch.autocast("cpu", dtype=torch.bfloat16, enabled=args.dtype == "bfloat16")

    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    net = PaperNetwork()
    obs = torch.rand(args.seq, args.batch, 3, OBS_SIDE, OBS_SIDE)
    actions = torch.randint(0, N_ACTIONS, (args.seq, args.batch))

    def gradient_step():
        with compute:
            value, logits, decoded = net(obs, actions)
            loss = (
                value.pow(2).mean() - torch.log_softmax(logits, dim=-1).mean() + (decoded - obs).abs().mean()
            )
        net.zero_grad(set_to_none=True)
        loss.backward()

    @torch.no_grad()
    def forward_step():
        with compute:
            net(obs, actions)

    samples = args.seq * args.batch
    result = {
        "framework": f"torch {torch.__version__}",
        "threads": args.threads,
        "dtype": args.dtype,
        "samples": samples,
        "params": sum(p.numel() for p in net.parameters()),
        "grad_samples_per_s": round(samples_per_second(gradient_step, samples, args.reps)),
        "forward_samples_per_s": round(samples_per_second(forward_step, samples, args.reps)),
    }
    print(json.dumps(result), flush=True)


if __name__ == "__main__":
    main()
