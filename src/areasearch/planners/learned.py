"""A learned goal planner: the DA-HGNN (or NCM) network of :mod:`areasearch.models.dahgnn` behind the
planner interface.

``LearnedPlanner(weights="path/to/policy")`` loads ``policy.safetensors`` + ``policy.json`` (never a
pickle; a file that does not match its JSON raises :class:`~areasearch.errors.ConfigError` naming
it); without ``weights`` the network is built with freshly initialised weights from ``seed`` (for
tests and as an untrained reference). Every decision it calls :func:`areasearch.models.dahgnn.decide`: the
actor on the observation's heterogeneous graph and the assignment on the Sinkhorn correspondence
matrix S that gives distinct goals while there are enough. It runs on the CPU unless ``device`` asks
for CUDA.

Registered as ``dahgnn-untrained`` and ``ncm-untrained`` (fresh weights, the paper's architecture
and the NCM preset) and, for each trained policy shipped in ``areasearch/policies/``, under its name
(``dahgnn``, ``ncm``, ``dahgnn-no-type``, ``dahgnn-no-history``; see
:data:`areasearch.planners.SHIPPED_POLICIES`). Each of them takes ``weights`` of your own instead
(``make_planner("dahgnn", weights="runs/x/policy")``, ``--weights runs/x/policy``): the network is then
the one those files describe, and :attr:`LearnedPlanner.weights_sha256` names the weights loaded.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import ConfigError

if TYPE_CHECKING:
    from ..models.network_config import NetworkConfig


def weights_file(prefix: str | os.PathLike[str]) -> Path:
    """The weights file of the policy ``prefix``: ``<prefix>.safetensors``."""
    path = Path(prefix)
    return path.with_name(path.name + ".safetensors")


def weights_sha256(prefix: str | os.PathLike[str]) -> str:
    """SHA-256 (hex) of ``<prefix>.safetensors``: what names a policy's weights in answers, summaries
    and ``policies.json``; ConfigError naming the file when it cannot be read."""
    path = weights_file(prefix)
    try:
        with open(path, "rb") as file:
            return hashlib.file_digest(file, "sha256").hexdigest()
    except OSError as error:
        raise ConfigError(f"{path}: cannot read the weights: {error.strerror or error}") from None


def architecture_name(config: NetworkConfig) -> str:
    """The learned method a network of ``config`` is: ``ncm`` for the NCM preset's architecture,
    ``dahgnn-no-type`` / ``dahgnn-no-history`` for the paper's ablations, else ``dahgnn``."""
    import dataclasses

    from ..models.network_config import NetworkConfig

    ncm = NetworkConfig.ncm()
    fields = [f.name for f in dataclasses.fields(NetworkConfig) if f.name != "graph"]
    if all(getattr(config, name) == getattr(ncm, name) for name in fields):
        return "ncm"
    if not config.type_aware:
        return "dahgnn-no-type"
    if not config.history:
        return "dahgnn-no-history"
    return "dahgnn"


@dataclass(eq=False)
class LearnedPlanner:
    """Goals from a DA-HGNN / NCM network."""

    weights: str | None = None
    """Path prefix of ``<prefix>.safetensors`` and ``<prefix>.json``; None: fresh weights from ``seed``."""
    preset: str = "dahgnn"
    """Architecture when ``weights`` is None: ``dahgnn`` (the paper's) or ``ncm`` (the NCM baseline)."""
    seed: int = 0
    """Seed of the fresh weights (when ``weights`` is None)."""
    device: str = "cpu"
    """``cpu`` or ``cuda``."""
    name: str = "dahgnn"
    """Registry name, for reports."""
    threads: int = 1
    """PyTorch CPU threads used while deciding (restored afterwards). One decision is a few
    milliseconds of small tensors: more threads only add synchronisation, and evaluation already
    runs one episode per worker process."""
    _model: Any = field(default=None, init=False, repr=False)
    _sha256: str | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        import torch

        from ..models.network import DAHGNN
        from ..models.network_config import NetworkConfig
        from ..models.weights import load_policy

        weights = self.weights
        if weights is not None and (not isinstance(weights, (str, os.PathLike)) or not os.fspath(weights)):
            raise ConfigError(f"weights must be a path prefix (PREFIX.safetensors + PREFIX.json), got {weights!r}")
        if isinstance(self.threads, bool) or not isinstance(self.threads, int) or self.threads < 1:
            raise ConfigError(f"threads must be a positive integer, got {self.threads!r}")
        if self.device not in ("cpu", "cuda"):
            raise ConfigError(f"device must be 'cpu' or 'cuda', got {self.device!r}")
        if self.device == "cuda" and not torch.cuda.is_available():
            raise ConfigError("device 'cuda' asked for, but PyTorch sees no CUDA device")
        if self.weights is not None:
            self._model, _ = load_policy(self.weights, device=self.device)
            self._sha256 = weights_sha256(self.weights)
        else:
            if self.preset not in ("dahgnn", "ncm"):
                raise ConfigError(f"preset must be 'dahgnn' or 'ncm', got {self.preset!r}")
            config = NetworkConfig.ncm() if self.preset == "ncm" else NetworkConfig()
            generator_state = torch.random.get_rng_state()
            torch.manual_seed(self.seed)
            try:
                self._model = DAHGNN(config).to(self.device)
            finally:
                torch.random.set_rng_state(generator_state)
        self._model.eval()

    @property
    def config(self) -> NetworkConfig:
        """The network's architecture (from the policy JSON, or the preset)."""
        config: NetworkConfig = self._model.config
        return config

    @property
    def weights_sha256(self) -> str | None:
        """SHA-256 of the loaded ``<weights>.safetensors`` (:func:`weights_sha256`); None for fresh weights."""
        return self._sha256

    def reset(self, rng: np.random.Generator) -> None:
        """Nothing to reset: evaluation-time goals are deterministic."""

    def assign(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        import torch

        from ..models.dahgnn import decide

        before = torch.get_num_threads()
        if before != self.threads:
            torch.set_num_threads(self.threads)
        try:
            return decide(self._model, obs)[0].cpu().numpy().astype(np.int64)
        finally:
            if before != self.threads:
                torch.set_num_threads(before)
