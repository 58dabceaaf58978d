"""A DiffusionNet-style network (Sharp et al., "DiffusionNet", TOG 2022) in PyTorch.

Each block diffuses its features with a learned time per channel in the Laplacian
eigenbasis, adds rotation-invariant products of spatial gradients, and mixes the
result with a per-vertex MLP and a residual connection.

Shapes use one set of names throughout: V vertices, C channels, K eigenpairs.
All operators are precomputed once per shape (:func:`prepare_shape`) and passed to
``forward``; nothing geometric is computed inside the network.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import torch
from torch import nn

from features.wks import wave_kernel_signature
from spidermatch.geometry.mesh import Mesh
from spidermatch.geometry.operators import Operators, cached_operators

logger = logging.getLogger(__name__)

INPUT_KINDS = ("wks", "xyz", "wks_xyz")
XYZ_CHANNELS = 3


@dataclass
class ModelConfig:
    """Hyper-parameters of :class:`DiffusionNet` and of its input features.

    Attributes
    ----------
    input : str
        ``"wks"`` (Wave Kernel Signature, invariant to rigid motion), ``"xyz"``
        (centred coordinates scaled to unit surface area) or ``"wks_xyz"`` (both,
        concatenated: WKS for the intrinsic shape, xyz to tell the left of
        consistently aligned shapes from their right).
    in_channels : int
        Input channels C_in (the WKS dimension; 3 for ``"xyz"``; the WKS dimension + 3
        for ``"wks_xyz"``).
    out_channels : int
        Output descriptor dimension C_out.
    width : int
        Channels C inside the blocks.
    n_blocks : int
        Number of diffusion blocks.
    n_eig : int
        Laplacian eigenpairs K used for diffusion and for the WKS input.
    mlp_layers : int
        Hidden layers of each block's per-vertex MLP.
    dropout : float
        Dropout probability inside the MLPs (0 disables it).
    gradient_features : bool
        Use the spatial gradient features.

    """

    input: str = "wks"
    in_channels: int = 128
    out_channels: int = 128
    width: int = 128
    n_blocks: int = 4
    n_eig: int = 128
    mlp_layers: int = 2
    dropout: float = 0.0
    gradient_features: bool = True

    def __post_init__(self) -> None:
        if self.input not in INPUT_KINDS:
            raise ValueError(f"model input must be one of {INPUT_KINDS}, got {self.input!r}")
        if self.input == "xyz" and self.in_channels != 3:
            raise ValueError(f"xyz input has 3 channels, but in_channels = {self.in_channels}")
        if self.input == "wks_xyz" and self.in_channels <= XYZ_CHANNELS:
            raise ValueError(f"wks_xyz input needs in_channels > 3 (WKS + xyz), got {self.in_channels}")
        for key in ("in_channels", "out_channels", "width", "n_blocks", "n_eig"):
            if getattr(self, key) < 1:
                raise ValueError(f"model {key} must be positive, got {getattr(self, key)}")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"model dropout must lie in [0, 1), got {self.dropout}")


@dataclass(frozen=True, eq=False)
class TorchOperators:
    """Operators of one shape as float tensors, scaled to unit surface area.

    Attributes
    ----------
    mass : torch.Tensor, shape (V,)
        Lumped vertex areas (they sum to 1).
    evals : torch.Tensor, shape (K,)
        Laplacian eigenvalues, ascending.
    evecs : torch.Tensor, shape (V, K)
        Mass-orthonormal eigenvectors.
    evecs_trans : torch.Tensor, shape (K, V)
        ``evecs.T @ diag(mass)``, the projection onto the eigenbasis.
    grad_x, grad_y : torch.Tensor, sparse, shape (V, V)
        Tangent-plane gradient components (frame axes e1 and e2).

    """

    mass: torch.Tensor
    evals: torch.Tensor
    evecs: torch.Tensor
    evecs_trans: torch.Tensor
    grad_x: torch.Tensor
    grad_y: torch.Tensor

    @property
    def n_verts(self) -> int:
        """Number of vertices V."""
        return int(self.mass.shape[0])

    @property
    def k(self) -> int:
        """Number of eigenpairs K."""
        return int(self.evals.shape[0])

    @classmethod
    def from_operators(
        cls, ops: Operators, area: float, k: int | None = None, dtype: torch.dtype = torch.float32
    ) -> TorchOperators:
        """Convert float64 :class:`spidermatch.geometry.operators.Operators` (with gradients) once.

        The shape is rescaled analytically to unit area (scale s = 1 / sqrt(area)):
        eigenvalues times area, eigenvectors and gradients times sqrt(area), mass
        divided by area.

        Parameters
        ----------
        ops : Operators
            Must carry ``grad_x`` and ``grad_y`` (``cached_operators(..., gradients=True)``).
        area : float
            Total surface area of the mesh.
        k : int, optional
            Keep only the first k eigenpairs (default: all K).

        """
        if ops.grad_x is None or ops.grad_y is None:
            raise ValueError("DiffusionNet needs gradient operators: use gradients=True")
        if not area > 0:
            raise ValueError(f"surface area must be positive, got {area}")
        k = ops.k if k is None else k
        if k > ops.k:
            raise ValueError(f"asked for {k} eigenpairs but the operators hold only {ops.k}")
        root = float(np.sqrt(area))
        mass = ops.mass / area
        evecs = ops.evecs[:, :k] * root

        def dense(array: np.ndarray) -> torch.Tensor:
            return torch.from_numpy(np.ascontiguousarray(array)).to(dtype)

        return cls(
            mass=dense(mass),
            evals=dense(ops.evals[:k] * area),
            evecs=dense(evecs),
            evecs_trans=dense((evecs * mass[:, None]).T),
            grad_x=_sparse_tensor(ops.grad_x * root, dtype),
            grad_y=_sparse_tensor(ops.grad_y * root, dtype),
        )


def _sparse_tensor(matrix: sp.spmatrix, dtype: torch.dtype) -> torch.Tensor:
    """Coalesced sparse COO tensor of a scipy matrix, shape (V, V)."""
    coo = matrix.tocoo()
    indices = torch.from_numpy(np.stack([coo.row, coo.col]).astype(np.int64))
    values = torch.from_numpy(coo.data).to(dtype)
    return torch.sparse_coo_tensor(indices, values, coo.shape, check_invariants=True).coalesce()


@dataclass(frozen=True, eq=False)
class ShapeInput:
    """Everything the network needs for one shape.

    Attributes
    ----------
    features : torch.Tensor, shape (V, C_in)
        Input features (WKS or scaled xyz).
    ops : TorchOperators
        Precomputed operators, unit-area scale.

    """

    features: torch.Tensor
    ops: TorchOperators


def input_features(
    mesh: Mesh, ops: Operators, config: ModelConfig, scale_area: float | None = None
) -> np.ndarray:
    """Input features of ``mesh`` for the network.

    Parameters
    ----------
    mesh : Mesh
        V vertices.
    ops : Operators
        The mesh's operators with at least ``config.n_eig`` eigenpairs.
    config : ModelConfig
    scale_area : float, optional
        The area that sets the unit of length (default: the mesh's own). A part of a
        surface (a partial scan) is measured in the unit of the whole it belongs to, so that
        its input and diffusion times match the whole's (see :mod:`spidermatch.geometry.partial`).

    Returns
    -------
    np.ndarray, shape (V, C_in), float64
        WKS rows (L2-normalised; computed from the eigenvalues of the shape scaled to
        unit area, so invariant to rigid motion and scale), centred coordinates
        divided by sqrt(area), or both side by side (xyz in the last 3 columns).

    """
    area = mesh.area if scale_area is None else float(scale_area)
    centred = (mesh.verts - mesh.verts.mean(axis=0)) / np.sqrt(area)
    if config.input == "xyz":
        return centred
    n_wks = config.in_channels - (XYZ_CHANNELS if config.input == "wks_xyz" else 0)
    # eigenvalues of the unit-area shape: invariant to scale
    wks = wave_kernel_signature(ops.evals[: config.n_eig] * area, ops.evecs[:, : config.n_eig], n_wks)
    return wks if config.input == "wks" else np.concatenate([wks, centred], axis=1)


def prepare_shape(
    mesh: Mesh,
    config: ModelConfig,
    use_cache: bool = True,
    dtype: torch.dtype = torch.float32,
    scale_area: float | None = None,
) -> ShapeInput:
    """Compute (or load from the operator cache) the network input of one mesh.

    Parameters
    ----------
    mesh : Mesh
        V vertices.
    config : ModelConfig
        Gives the input kind, C_in and K = ``n_eig``.
    use_cache : bool
        Use the on-disk operator cache of :func:`spidermatch.geometry.operators.cached_operators`.
    dtype : torch.dtype
    scale_area : float, optional
        The area that sets the unit of length (see :func:`input_features`).

    Returns
    -------
    ShapeInput
        features (V, C_in) and operators with K eigenpairs.

    """
    ops = cached_operators(mesh, k=config.n_eig, gradients=True, use_cache=use_cache)
    if ops.k < config.n_eig:
        logger.warning("%s: only %d eigenpairs available (asked %d)", mesh.name, ops.k, config.n_eig)
    area = mesh.area if scale_area is None else float(scale_area)
    features = input_features(mesh, ops, config, area)
    torch_ops = TorchOperators.from_operators(ops, area, dtype=dtype)
    return ShapeInput(torch.from_numpy(np.ascontiguousarray(features)).to(dtype), torch_ops)


class LearnedTimeDiffusion(nn.Module):
    """Heat diffusion with one learned time t_c >= 0 per channel, in the eigenbasis.

    ``x -> evecs @ (exp(-evals t) * (evecs.T @ (mass * x)))``.

    Parameters
    ----------
    channels : int
        Number of channels C.

    """

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.channels = channels
        self.diffusion_time = nn.Parameter(torch.zeros(channels))

    def forward(self, x: torch.Tensor, ops: TorchOperators) -> torch.Tensor:
        """Diffuse ``x`` of shape (V, C); returns shape (V, C)."""
        _check_channels("LearnedTimeDiffusion", x, self.channels)
        time = self.diffusion_time.clamp(min=1e-8)
        spectral = ops.evecs_trans @ x  # (K, C)
        spectral = spectral * torch.exp(-ops.evals[:, None] * time[None, :])
        return ops.evecs @ spectral


class SpatialGradientFeatures(nn.Module):
    """Rotation-invariant products of per-vertex gradients, as in DiffusionNet.

    With gradients g = g_x + i g_y seen as complex numbers per channel, a learned
    complex-linear map A = A_re + i A_im mixes channels and the feature is
    ``tanh(Re(conj(g) * (A g)))``, invariant to the choice of tangent frame.

    Parameters
    ----------
    channels : int
        Number of channels C.

    """

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.channels = channels
        self.rotation_re = nn.Linear(channels, channels, bias=False)
        self.rotation_im = nn.Linear(channels, channels, bias=False)

    def forward(self, grad_x: torch.Tensor, grad_y: torch.Tensor) -> torch.Tensor:
        """Gradient components (V, C) each; returns features of shape (V, C)."""
        _check_channels("SpatialGradientFeatures", grad_x, self.channels)
        if grad_y.shape != grad_x.shape:
            raise ValueError(
                f"gradient components differ in shape: {tuple(grad_x.shape)} vs {tuple(grad_y.shape)}"
            )
        rotated_x = self.rotation_re(grad_x) - self.rotation_im(grad_y)
        rotated_y = self.rotation_re(grad_y) + self.rotation_im(grad_x)
        return torch.tanh(grad_x * rotated_x + grad_y * rotated_y)


def vertex_mlp(channels: list[int], dropout: float) -> nn.Sequential:
    """Per-vertex MLP: Linear (+ReLU, +dropout) layers with the given channel counts.

    Parameters
    ----------
    channels : list of int
        ``[C_in, C_hidden, ..., C_out]``; no activation after the last layer.
    dropout : float
        Dropout probability before each hidden linear layer.

    """
    layers: list[nn.Module] = []
    for i, (c_in, c_out) in enumerate(zip(channels[:-1], channels[1:])):
        if i > 0 and dropout > 0:
            layers.append(nn.Dropout(dropout))
        layers.append(nn.Linear(c_in, c_out))
        if i < len(channels) - 2:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


class DiffusionNetBlock(nn.Module):
    """Diffusion, gradient features, per-vertex MLP and a residual connection.

    Parameters
    ----------
    width : int
        Channels C in and out.
    mlp_layers : int
        Hidden layers of the MLP (each of width C).
    dropout : float
        MLP dropout probability.
    gradient_features : bool
        Concatenate the spatial gradient features.

    """

    def __init__(
        self, width: int, mlp_layers: int = 2, dropout: float = 0.0, gradient_features: bool = True
    ) -> None:
        super().__init__()
        self.width = width
        self.diffusion = LearnedTimeDiffusion(width)
        self.gradient = SpatialGradientFeatures(width) if gradient_features else None
        n_parts = 3 if gradient_features else 2
        self.mlp = vertex_mlp([n_parts * width] + [width] * mlp_layers + [width], dropout)

    def forward(self, x: torch.Tensor, ops: TorchOperators) -> torch.Tensor:
        """Features (V, C) -> features (V, C)."""
        diffused = self.diffusion(x, ops)
        parts = [x, diffused]
        if self.gradient is not None:
            grad_x = torch.sparse.mm(ops.grad_x, diffused)
            grad_y = torch.sparse.mm(ops.grad_y, diffused)
            parts.append(self.gradient(grad_x, grad_y))
        return x + self.mlp(torch.cat(parts, dim=1))


class DiffusionNet(nn.Module):
    """Linear lift, ``n_blocks`` :class:`DiffusionNetBlock` and a linear output layer.

    Parameters
    ----------
    in_channels : int
        Input channels C_in.
    out_channels : int
        Output channels C_out.
    width : int
        Channels C of the blocks.
    n_blocks : int
        Number of blocks.
    mlp_layers, dropout, gradient_features
        Passed to every block.

    """

    def __init__(
        self,
        in_channels: int = 128,
        out_channels: int = 128,
        width: int = 128,
        n_blocks: int = 4,
        mlp_layers: int = 2,
        dropout: float = 0.0,
        gradient_features: bool = True,
    ) -> None:
        super().__init__()
        self.in_channels = in_channels
        self.out_channels = out_channels
        self.lift = nn.Linear(in_channels, width)
        self.blocks = nn.ModuleList(
            DiffusionNetBlock(width, mlp_layers, dropout, gradient_features) for _ in range(n_blocks)
        )
        self.project = nn.Linear(width, out_channels)

    @classmethod
    def from_config(cls, config: ModelConfig) -> DiffusionNet:
        """Build the network described by ``config``."""
        return cls(
            config.in_channels,
            config.out_channels,
            config.width,
            config.n_blocks,
            config.mlp_layers,
            config.dropout,
            config.gradient_features,
        )

    def forward(self, x: torch.Tensor, ops: TorchOperators) -> torch.Tensor:
        """Per-vertex descriptors.

        Parameters
        ----------
        x : torch.Tensor, shape (V, C_in)
        ops : TorchOperators
            Operators of the same shape (V vertices).

        Returns
        -------
        torch.Tensor, shape (V, C_out)

        """
        _check_channels("DiffusionNet", x, self.in_channels)
        if x.shape[0] != ops.n_verts:
            raise ValueError(
                f"DiffusionNet: features have {x.shape[0]} vertices but the operators have {ops.n_verts}"
            )
        x = self.lift(x)
        for block in self.blocks:
            x = block(x, ops)
        return self.project(x)


def _check_channels(where: str, x: torch.Tensor, expected: int) -> None:
    """Raise ValueError unless ``x`` has shape (V, expected)."""
    if x.ndim != 2:
        raise ValueError(f"{where}: expected features of shape (V, {expected}), got {tuple(x.shape)}")
    if x.shape[1] != expected:
        raise ValueError(f"{where}: expected {expected} channels, got {x.shape[1]}")
