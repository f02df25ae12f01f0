"""Convolutional building blocks shared by CMAL and BiGAN.

Every network is a DCGAN-style pyramid: a frame of ``S x S`` pixels (``S`` a power of two,
at least 8) is halved ``log2(S) - 2`` times down to ``4 x 4`` by 4x4 stride-2 convolutions,
and the decoder mirrors it with 4x4 stride-2 transposed convolutions. Channel counts double at
each level starting from ``width`` (``width=16`` at 64x64 gives 16, 32, 64, 128), so one
``width`` key scales every network (16 trains on 2 CPU cores; 64 is a GPU-sized setting).

How a condition enters a network (the paper is silent; see ``conf/model/cmal.yaml``):

- encoder ``En(x | c)`` and classifier-free nets: the one-hot condition is broadcast as extra
  input channels (StarGAN style);
- decoder ``De(z | c)``: the one-hot is concatenated to the code and, again, broadcast as extra
  channels at the input of every up-sampling block, so the weather can be painted in at every
  scale;
- discriminator ``D(x | c)``: a projection discriminator (Miyato & Koyama 2018),
  ``D(x|c) = w . phi(x) + <embed(c), phi(x)>``, the standard way to condition a GAN critic on
  a class; spectral normalisation keeps it 1-Lipschitz-ish and stabilises the plain
  (log-loss) GAN objective of the paper.
"""

from __future__ import annotations

import math

import torch
from torch import nn
from torch.nn.utils.parametrizations import spectral_norm

from cmal_lcd.models.config import NORMS  # the normalisations a network can use


def pyramid_depth(image_size: int) -> int:
    """Number of stride-2 levels from ``image_size`` down to 4x4.

    Parameters
    ----------
    image_size : int
        Side of the square input, a power of two >= 8.

    Returns
    -------
    int
        ``log2(image_size) - 2``.

    Raises
    ------
    ValueError
        Naming ``image_size`` when it is not a power of two >= 8.
    """
    if not isinstance(image_size, int) or image_size < 8 or image_size & (image_size - 1):
        raise ValueError(f"image_size: expected a power of two >= 8, got {image_size!r}")
    return int(math.log2(image_size)) - 2


def pyramid_widths(image_size: int, width: int) -> list[int]:
    """Channels at each down-sampling level: ``width * 2**level``.

    Returns
    -------
    list of int
        One entry per level (``pyramid_depth(image_size)`` entries).
    """
    if width < 1:
        raise ValueError(f"width: expected >= 1, got {width}")
    return [width * 2**level for level in range(pyramid_depth(image_size))]


def check_norm(kind: str) -> str:
    """Raise ``ValueError`` naming ``norm`` unless ``kind`` is one of :data:`NORMS`."""
    if kind not in NORMS:
        raise ValueError(f"norm: expected one of {NORMS}, got {kind!r}")
    return kind


def norm_layer(kind: str, channels: int) -> nn.Module:
    """A normalisation layer by name (``instance``, ``batch`` or ``none``)."""
    if kind == "instance":
        # affine: learns a per-channel scale/shift; no running stats, so a code never depends
        # on the other frames of the batch or on train/eval mode.
        return nn.InstanceNorm2d(channels, affine=True)
    if kind == "batch":
        return nn.BatchNorm2d(channels)
    if kind == "none":
        return nn.Identity()
    raise ValueError(f"norm: expected one of {NORMS}, got {kind!r}")


def broadcast_condition(x: torch.Tensor, condition: torch.Tensor | None) -> torch.Tensor:
    """Append a per-frame condition vector to ``x`` as constant feature maps.

    Parameters
    ----------
    x : Tensor, shape (N, C, H, W)
    condition : Tensor, shape (N, K), or None
        One-hot (or soft) condition; ``None`` returns ``x`` unchanged.

    Returns
    -------
    Tensor, shape (N, C + K, H, W)
    """
    if condition is None:
        return x
    n, _, h, w = x.shape
    return torch.cat([x, condition[:, :, None, None].expand(n, condition.shape[1], h, w)], dim=1)


class DownPyramid(nn.Module):
    """4x4 stride-2 convolutions from ``image_size`` to 4x4, then a flatten.

    Parameters
    ----------
    in_channels : int
        Channels of the input (3 for RGB, plus conditions when broadcast).
    image_size, width : int
        See :func:`pyramid_widths`.
    norm : str
        Normalisation after every convolution but the first (DCGAN practice).
    spectral : bool
        Wrap each convolution in spectral normalisation (discriminators).

    Notes
    -----
    ``forward(x (N, in_channels, S, S)) -> (N, out_features)`` with
    ``out_features = widths[-1] * 16``.
    """

    def __init__(self, in_channels: int, *, image_size: int, width: int, norm: str = "none",
                 spectral: bool = False):
        super().__init__()
        check_norm(norm)
        widths = pyramid_widths(image_size, width)
        layers: list[nn.Module] = []
        previous = in_channels
        for level, channels in enumerate(widths):
            conv = nn.Conv2d(previous, channels, 4, stride=2, padding=1, bias=norm != "batch")
            layers.append(spectral_norm(conv) if spectral else conv)
            if level > 0:
                layers.append(norm_layer(norm, channels))
            layers.append(nn.LeakyReLU(0.2))
            previous = channels
        self.body = nn.Sequential(*layers)
        self.out_features = widths[-1] * 16

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.body(x).flatten(1)


class Encoder(nn.Module):
    """``En(x | c)``: frame (and condition) to a code of ``code_dim`` floats.

    Parameters
    ----------
    image_size, width : int
        Pyramid size (see :func:`pyramid_widths`).
    code_dim : int
        Length of the code (1024 in the paper, section IV-D).
    n_conditions : int
        Conditions broadcast as input channels; 0 for an unconditional encoder (BiGAN ``E``).
    norm : str
        ``instance`` by default: instance normalisation removes per-frame channel statistics
        (global brightness, contrast, tint), which is where most of the weather lives.

    Notes
    -----
    ``forward(x (N, 3, S, S), condition (N, n_conditions) or None) -> (N, code_dim)``.
    """

    def __init__(self, *, image_size: int, width: int, code_dim: int, n_conditions: int = 0,
                 norm: str = "instance"):
        super().__init__()
        self.n_conditions = n_conditions
        self.trunk = DownPyramid(3 + n_conditions, image_size=image_size, width=width, norm=norm)
        self.head = nn.Linear(self.trunk.out_features, code_dim)

    def forward(self, x: torch.Tensor, condition: torch.Tensor | None = None) -> torch.Tensor:
        if (condition is None) != (self.n_conditions == 0):
            raise ValueError("condition: expected one exactly when the encoder is conditional")
        return self.head(self.trunk(broadcast_condition(x, condition)))


class Decoder(nn.Module):
    """``De(z | c)``: code (and condition) to a frame in ``[-1, 1]``.

    Parameters
    ----------
    image_size, width, code_dim, n_conditions : int
        As for :class:`Encoder`; the decoder mirrors its pyramid.
    norm : str
        ``batch`` by default (DCGAN generator). Instance normalisation would erase the per-frame
        colour statistics the decoder has to produce for each weather.

    Notes
    -----
    ``forward(z (N, code_dim), condition (N, n_conditions) or None) -> (N, 3, S, S)``.
    """

    def __init__(self, *, image_size: int, width: int, code_dim: int, n_conditions: int = 0,
                 norm: str = "batch"):
        super().__init__()
        check_norm(norm)
        widths = pyramid_widths(image_size, width)[::-1]
        self.n_conditions = n_conditions
        self.top_channels = widths[0]
        self.stem = nn.Sequential(nn.Linear(code_dim + n_conditions, widths[0] * 16),
                                  nn.ReLU())
        self.blocks = nn.ModuleList()
        for level, channels in enumerate(widths):
            last = level == len(widths) - 1
            out = 3 if last else widths[level + 1]
            conv = nn.ConvTranspose2d(channels + n_conditions, out, 4, stride=2, padding=1)
            block = [conv, nn.Tanh()] if last else [conv, norm_layer(norm, out), nn.ReLU()]
            self.blocks.append(nn.Sequential(*block))

    def forward(self, z: torch.Tensor, condition: torch.Tensor | None = None) -> torch.Tensor:
        if (condition is None) != (self.n_conditions == 0):
            raise ValueError("condition: expected one exactly when the decoder is conditional")
        stem_in = z if condition is None else torch.cat([z, condition], dim=1)
        h = self.stem(stem_in).view(z.shape[0], self.top_channels, 4, 4)
        for block in self.blocks:
            h = block(broadcast_condition(h, condition))
        return h


class ProjectionDiscriminator(nn.Module):
    """``D(x | c)``: logit that ``x`` is a real frame of condition ``c``.

    ``D(x|c) = w . phi(x) + b + <E c, phi(x)>`` with ``phi`` a spectrally normalised
    :class:`DownPyramid` and ``E`` an embedding of the (one-hot or soft) condition.

    Notes
    -----
    ``forward(x (N, 3, S, S), condition (N, n_conditions)) -> (N,)`` logits.
    """

    def __init__(self, *, image_size: int, width: int, n_conditions: int):
        super().__init__()
        self.trunk = DownPyramid(3, image_size=image_size, width=width, norm="none",
                                 spectral=True)
        self.linear = spectral_norm(nn.Linear(self.trunk.out_features, 1))
        self.embed = spectral_norm(nn.Linear(n_conditions, self.trunk.out_features, bias=False))

    def forward(self, x: torch.Tensor, condition: torch.Tensor) -> torch.Tensor:
        features = self.trunk(x)
        projection = (self.embed(condition) * features).sum(dim=1)
        return self.linear(features).squeeze(1) + projection


class ConditionClassifier(nn.Module):
    """``C(x)``: logits over the weather conditions.

    No normalisation: instance norm would remove exactly the global statistics that tell the
    weather apart, and batch norm would make a prediction depend on the batch.

    Notes
    -----
    ``forward(x (N, 3, S, S)) -> (N, n_conditions)`` logits.
    """

    def __init__(self, *, image_size: int, width: int, n_conditions: int):
        super().__init__()
        self.trunk = DownPyramid(3, image_size=image_size, width=width, norm="none")
        self.head = nn.Linear(self.trunk.out_features, n_conditions)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.head(self.trunk(x))


class JointDiscriminator(nn.Module):
    """BiGAN ``D(x, z)``: logit that the pair (frame, code) comes from the encoder.

    The frame goes through a spectrally normalised :class:`DownPyramid`, the code through a
    linear layer, and an MLP scores the concatenation (Donahue et al. 2017). Every layer is
    spectrally normalised.

    Parameters
    ----------
    image_size, width, code_dim : int
    hidden : int
        Width of the joint MLP (and of the frame and code embeddings).
    dropout : float
        Dropout on the frame and code embeddings and on the hidden layer of the joint MLP, in
        training mode (ALI, Dumoulin et al. 2017, uses 0.2 in its joint discriminator). Applied
        functionally, so the state_dict is the same for every value; 0 computes exactly what the
        discriminator without the option did.
    prior_std : float
        The code enters as ``z / prior_std`` (unit scale for prior draws whatever the prior).
    unary : bool
        Also score the frame and the code alone (BigBiGAN, Donahue & Simonyan 2019):
        ``s_x = w_x . h_x`` and ``s_z = w_z . h_z`` on the two embeddings, two extra linear
        heads built only when on. ``s_z`` is a critic of the code marginal alone, which gives
        the encoder a direct signal towards the prior even while the joint score is decided by
        the frames.

    Notes
    -----
    ``forward(x (N, 3, S, S), z (N, code_dim)) -> (N,)`` joint logits;
    ``scores(x, z) -> (N, 3)`` (joint, frame, code) with ``unary``, else ``(N, 1)``.
    """

    def __init__(self, *, image_size: int, width: int, code_dim: int, hidden: int = 256,
                 dropout: float = 0.0, prior_std: float = 1.0, unary: bool = False):
        super().__init__()
        if not 0.0 <= dropout < 1.0:
            raise ValueError(f"dropout: expected 0 <= dropout < 1, got {dropout}")
        self.dropout = float(dropout)
        self.prior_std = float(prior_std)
        self.trunk = DownPyramid(3, image_size=image_size, width=width, norm="none",
                                 spectral=True)
        self.x_head = spectral_norm(nn.Linear(self.trunk.out_features, hidden))
        self.z_head = spectral_norm(nn.Linear(code_dim, hidden))
        self.joint = nn.Sequential(nn.LeakyReLU(0.2), spectral_norm(nn.Linear(2 * hidden, hidden)),
                                   nn.LeakyReLU(0.2), spectral_norm(nn.Linear(hidden, 1)))
        self.unary = bool(unary)
        if self.unary:
            self.x_score = spectral_norm(nn.Linear(hidden, 1))
            self.z_score = spectral_norm(nn.Linear(hidden, 1))

    def _drop(self, h: torch.Tensor) -> torch.Tensor:
        if self.dropout == 0.0:
            return h
        return nn.functional.dropout(h, p=self.dropout, training=self.training)

    def scores(self, x: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        if self.prior_std != 1.0:
            z = z / self.prior_std
        h_x, h_z = self.x_head(self.trunk(x)), self.z_head(z)
        h = torch.cat([h_x, h_z], dim=1)
        h = self.joint[1](self._drop(self.joint[0](h)))
        h = self.joint[3](self._drop(self.joint[2](h)))
        if not self.unary:
            return h
        s_x = self.x_score(self._drop(nn.functional.leaky_relu(h_x, 0.2)))
        s_z = self.z_score(self._drop(nn.functional.leaky_relu(h_z, 0.2)))
        return torch.cat([h, s_x, s_z], dim=1)

    def forward(self, x: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        return self.scores(x, z)[:, 0]


class CodeDiscriminator(nn.Module):
    """CMAL ``D_z(z | c)``: logit that code ``z`` is a draw of the prior ``P_Z``, under ``c``.

    Adversarial-autoencoder critic (Makhzani et al. 2016) made conditional the way ``D(x|c)``
    is: a projection head (Miyato & Koyama 2018) on a spectrally normalised two-layer MLP,
    ``D_z(z|c) = w . phi(z/s) + <E c, phi(z/s)>`` with ``s = prior_std``, so the MLP sees
    unit-scale inputs whatever the prior's scale. Because it is conditional, it can only be
    fooled when the codes of *every* condition follow the prior (eq. 7), not just their mix.

    Notes
    -----
    ``forward(z (N, code_dim), condition (N, n_conditions)) -> (N,)`` logits.
    """

    def __init__(self, *, code_dim: int, n_conditions: int, hidden: int = 256,
                 prior_std: float = 1.0):
        super().__init__()
        if hidden < 1:
            raise ValueError(f"hidden: expected >= 1, got {hidden}")
        self.prior_std = float(prior_std)
        self.phi = nn.Sequential(spectral_norm(nn.Linear(code_dim, hidden)), nn.LeakyReLU(0.2),
                                 spectral_norm(nn.Linear(hidden, hidden)), nn.LeakyReLU(0.2))
        self.linear = spectral_norm(nn.Linear(hidden, 1))
        self.embed = spectral_norm(nn.Linear(n_conditions, hidden, bias=False))

    def forward(self, z: torch.Tensor, condition: torch.Tensor) -> torch.Tensor:
        features = self.phi(z / self.prior_std)
        projection = (self.embed(condition) * features).sum(dim=1)
        return self.linear(features).squeeze(1) + projection


class CodeClassifier(nn.Module):
    """CMAL's latent weather adversary ``A(z)``: logits over the conditions from a code.

    A two-layer MLP on ``z / prior_std`` (no normalisation: it must be able to read the
    per-condition offset and scale of the codes, which is what it is there to detect).

    Notes
    -----
    ``forward(z (N, code_dim)) -> (N, n_conditions)`` logits.
    """

    def __init__(self, *, code_dim: int, n_conditions: int, hidden: int = 256,
                 prior_std: float = 1.0):
        super().__init__()
        if hidden < 1:
            raise ValueError(f"hidden: expected >= 1, got {hidden}")
        self.prior_std = float(prior_std)
        self.body = nn.Sequential(nn.Linear(code_dim, hidden), nn.LeakyReLU(0.2),
                                  nn.Linear(hidden, n_conditions))

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        return self.body(z / self.prior_std)
